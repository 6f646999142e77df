"""Images per second of descriptor extraction with the offline default model, at batch 1 and batch 16.

Two numbers per batch size, each the median of several timed runs after a warm-up run:

* model: the network alone on images already decoded and normalised (forward pass + L2 normalisation);
* end to end: ``extract_descriptors`` from JPEG files (decode in threads, preprocess, forward), in memory.

Images: the VPR-Bench corridor queries (160 x 120) from $VPR_UNCERTAINTY_DATA when present, else --dataset.
CPU timings are sensitive to other processes on the machine: the load average is printed with the results.

    python benchmarks/bench_extraction.py [--batch-sizes 1 16] [--repeats 5] [--images 64] [--image-size 224]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from vpr_uncertainty.descriptors import DEFAULT_MODEL, extract_descriptors, load_image, load_model
from vpr_uncertainty.descriptors.images import to_model_input


def default_folder() -> Path | None:
    data = os.environ.get("VPR_UNCERTAINTY_DATA")
    folder = Path(data) / "vprbench" / "corridor" / "query" if data else None
    return folder if folder is not None and folder.is_dir() else None


def median_seconds(function, repeats: int, warmup: int) -> float:
    for _ in range(warmup):
        function()
    durations = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        durations.append(time.perf_counter() - start)
    return statistics.median(durations)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"model name or TorchScript file ({DEFAULT_MODEL})")
    parser.add_argument("--dataset", type=Path, default=default_folder(), help="folder of images (default: corridor)")
    parser.add_argument("--images", type=int, default=64, help="images per timed run (default 64)")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 16], help="batch sizes (default 1 16)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per measurement, median reported")
    parser.add_argument("--warmup", type=int, default=1, help="untimed runs before timing (default 1)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    parser.add_argument("--image-size", type=int, help="resize the shorter side to this (default: the model's)")
    parser.add_argument("--threads", type=int, help="torch intra-op threads (default: torch's choice)")
    parser.add_argument("--workers", type=int, help="decoding threads of extract_descriptors (default its own)")
    args = parser.parse_args()
    if args.dataset is None:
        parser.error("no images: set VPR_UNCERTAINTY_DATA or pass --dataset FOLDER")

    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    paths = sorted(p for p in args.dataset.iterdir() if p.suffix.lower() in {".jpg", ".jpeg", ".png"})
    paths = (paths * (args.images // max(len(paths), 1) + 1))[: args.images]
    names = [f"{i:06d}" for i in range(len(paths))]
    model = load_model(args.model, device=args.device)
    if args.image_size:
        model.preprocessing = model.preprocessing.replace(image_size=args.image_size)
    decoded = [load_image(path, model.preprocessing) for path in paths]
    height, width = decoded[0].shape[:2]

    def synchronize() -> None:
        if torch.device(args.device).type == "cuda":
            torch.cuda.synchronize()

    print(f"model {model.name} on {args.device}, {torch.get_num_threads()} torch threads, {os.cpu_count()} CPUs")
    print(f"{len(paths)} images from {args.dataset}, model input {width} x {height}")
    print(f"median of {args.repeats} runs after {args.warmup} warm-up run(s)")
    print(f"{'batch':>5}  {'model img/s':>12}  {'ms/img':>8}  {'end-to-end img/s':>17}")
    for batch_size in args.batch_sizes:
        batches = [
            to_model_input(decoded[start : start + batch_size], model.preprocessing, model.device)
            for start in range(0, len(decoded), batch_size)
        ]

        def forward(batches=batches) -> None:
            for batch in batches:
                model(batch)
            synchronize()

        def end_to_end(batch_size=batch_size) -> None:
            extract_descriptors(model, paths, names, batch_size=batch_size, workers=args.workers, progress=False)

        model_s = median_seconds(forward, args.repeats, args.warmup)
        total_s = median_seconds(end_to_end, args.repeats, args.warmup)
        print(
            f"{batch_size:>5}  {len(paths) / model_s:>12.1f}  {model_s / len(paths) * 1e3:>8.2f}  "
            f"{len(paths) / total_s:>17.1f}"
        )
    if hasattr(os, "getloadavg"):
        print("load average (1, 5, 15 min): {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))


if __name__ == "__main__":
    main()
