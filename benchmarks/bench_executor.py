"""Extraction throughput with the local executor and with Ray at 1 and 2 workers, and Ray's start-up overhead.

On the 222 corridor images (111 database + 111 query), enlarged to ``--resize`` pixels wide (640 by default, the
size of most VPR benchmarks' images; 0 keeps the 160 x 120 originals), with the offline default model, batch size 16,
each run into a fresh HDF5 file. ``local`` is the in-process extraction as ``extract`` runs it (torch's default
threads, image decoding threads); ``ray N`` starts a local Ray cluster of N CPUs and runs the extraction as Ray
Data batch inference (``map_batches`` on a pool of N model actors, one model load each, one torch thread each),
counted in its time. Start-up is measured separately: ``ray.init`` of a local cluster, and the first written batch
of a 1-actor extraction (dataset start, actor process, model load and the first batch). Prints a Markdown table; on
a machine with C cores expect scaling only up to C.

    python benchmarks/bench_executor.py                  # VPR_UNCERTAINTY_DATA must point at the shared data
    python benchmarks/bench_executor.py --workers 1 2 4
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from functools import partial
from pathlib import Path

from bench_geometric import resized_copies
from vpr_uncertainty.executors import get_executor
from vpr_uncertainty.pipeline.extract import ExtractConf
from vpr_uncertainty.pipeline.extract import compute as extract


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"), help="shared data folder")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="Ray worker counts (default 1 2)")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--resize", type=int, default=640, help="extract from copies this wide (0: the originals)")
    return parser.parse_args(argv)


def corridor_images(data: Path) -> dict:
    root = data / "vprbench" / "corridor"
    splits = {}
    for split, folder in (("database", "ref"), ("queries", "query")):
        paths = sorted((root / folder).glob("*.jpg"))
        splits[split] = (paths, [p.name for p in paths])
    return splits


def timed_extraction(images: dict, batch_size: int, executor=None) -> float:
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        extract(ExtractConf(batch_size=batch_size, progress=False), images, Path(folder) / "d.h5", executor=executor)
        return time.perf_counter() - start


def startup_seconds(images: dict, batch_size: int) -> tuple[float, float]:
    """(ray.init of a local 1-CPU cluster, the first batch of a Ray Data extraction incl. model load) in seconds."""
    import ray

    from vpr_uncertainty.descriptors import extract_descriptors
    from vpr_uncertainty.pipeline.extract import model_of

    conf = ExtractConf(batch_size=batch_size, progress=False)
    model = model_of(conf)  # the driver's model, loaded before the clock starts
    paths, names = images["database"]
    start = time.perf_counter()
    ray.init(address="local", num_cpus=1, include_dashboard=False, log_to_driver=False)
    init = time.perf_counter() - start
    first: list[float] = []
    with get_executor("ray", workers=1) as executor:
        start = time.perf_counter()
        extract_descriptors(
            model,
            paths[:batch_size],
            names[:batch_size],
            batch_size=batch_size,
            progress=False,
            executor=executor,
            model_factory=partial(model_of, conf),
            on_batch=lambda _: first.append(time.perf_counter() - start),
        )
    ray.shutdown()
    return init, first[0]


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.data is None:
        raise SystemExit("set VPR_UNCERTAINTY_DATA or pass --data")
    images = corridor_images(args.data)
    count = sum(len(names) for _, names in images.values())
    with tempfile.TemporaryDirectory() as folder:
        if args.resize:
            images = {
                split: (resized_copies(paths, args.resize, Path(folder) / split), names)
                for split, (paths, names) in images.items()
            }
        init, first = startup_seconds(images, args.batch_size)
        rows = [("local", timed_extraction(images, args.batch_size))]
        for workers in args.workers:
            start = time.perf_counter()
            with get_executor("ray", workers=workers) as executor:
                timed_extraction(images, args.batch_size, executor)
            rows.append((f"ray {workers}", time.perf_counter() - start))
    side = f"{args.resize} px wide" if args.resize else "160x120"
    print(
        f"{count} corridor images ({side}), batch size {args.batch_size}, {os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.1f} at the end\n"
    )
    print("| executor | seconds (incl. Ray start) | images/s | vs local |")
    print("|---|---:|---:|---:|")
    for name, seconds in rows:
        print(f"| {name} | {seconds:.1f} | {count / seconds:.1f} | {rows[0][1] / seconds:.2f}x |")
    print(
        f"\nRay start-up: ray.init of a local cluster {init:.1f} s; first batch of {args.batch_size} images written "
        f"{first:.1f} s after the extraction started (Ray Data start, actor process, model load, first batch)"
    )


if __name__ == "__main__":
    main()
