"""The paper's study (9 VPR methods x 6 datasets, with geometric verification) projected from costs measured here.

What it counts (from the toolkit's own registries, not typed in): the database and query images of the six
datasets (``vpr_uncertainty.data.named_datasets``), the nine methods and their descriptor sizes
(``vpr_uncertainty.descriptors.models.HUB_MODELS``). What it measures, in this run, on this machine:

* extraction, seconds per image: the offline default model (EfficientNet-Lite0) through ``extract_descriptors`` on
  640-pixel-wide copies of corridor images (the size of most of the datasets' images), batch 16, median of repeats;
* retrieval, seconds per multiply-add: an exact Faiss inner-product search of random unit vectors;
* geometric verification (``GeometricVerifier``, all cores), seconds per image of local features and seconds per
  pair of matching + RANSAC, on 640-pixel copies of corridor queries and their NetVLAD top-1 matches;
* SU, seconds per query (batched, as ``evaluate`` times it); Ray's start-up (``ray.init`` of a local cluster).

The nine methods have other backbones than the offline model; their extraction cost is *estimated* by scaling the
measured cost with the backbone's multiply-adds at its input size (a FLOPs model: on a CPU, dense ResNet and ViT
convolutions/attention run closer to peak than EfficientNet's depthwise convolutions, so this overestimates them).
Geometric verification is projected for the verifiers that run offline here (SIFT by default).

The projection: work = items x seconds per item; one machine = this machine as measured; N workers = work / N plus
the measured Ray start-up, assuming each worker is as fast as this machine and no shared bottleneck (the image
files on a shared filesystem must keep up). A GPU worker is faster by a factor only a GPU can tell: measure it with
``bench_extraction.py --device cuda`` / ``bench_geometric.py --device cuda`` and pass ``--gpu-image-ms`` and
``--gpu-pair-ms`` to print the GPU projection too.

    python benchmarks/paper_scale_projection.py                      # VPR_UNCERTAINTY_DATA must be set
    python benchmarks/paper_scale_projection.py --workers 8 32 --gpu-image-ms 5 --gpu-pair-ms 84
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_geometric import resized_copies
from vpr_uncertainty.data.named_datasets import get_named_dataset
from vpr_uncertainty.descriptors import DEFAULT_MODEL, extract_descriptors, load_model
from vpr_uncertainty.descriptors.models import HUB_MODELS

#: The six datasets of the paper, by their names in the named-dataset registry.
PAPER_DATASETS = ("pitts250k", "st_lucia", "nordland", "amstertime", "eynsham", "tokyo247")
#: Backbone multiply-adds (G) for one 224 x 224 image, from the architectures' papers and torchvision's model
#: tables (ResNet-50 4.09, ResNet-101 7.80, VGG-16 15.47, ViT-B/16 17.56 at 197 tokens); DINOv2 ViT-B/14 and
#: ViT-G/14 at 257 tokens: ViT-B/16 x 257/197, and 1.1 G parameters x 257 tokens. EfficientNet-Lite0: 0.41.
GMACS_224 = {
    "ResNet-50": 4.09,
    "ResNet-101": 7.80,
    "VGG-16": 15.47,
    "DINOv2 ViT-B/14": 17.56 * 257 / 197,
    "DINOv2 ViT-G/14": 1.1 * 257,
    "EfficientNet-Lite0": 0.41,
}
#: The input size each method runs at: its fixed size, else the datasets' usual 640 x 480.
NATIVE_PIXELS = 640 * 480


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"), help="shared data")
    parser.add_argument("--workers", type=int, nargs="+", default=[8, 32, 64], help="worker counts to project")
    parser.add_argument("--images", type=int, default=48, help="images for the extraction measurement")
    parser.add_argument("--pairs", type=int, default=24, help="query/top-1 pairs for the GV measurement")
    parser.add_argument("--gv", default="GV-SIFT", help="comma-separated GV methods to measure and project")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats (medians are reported)")
    parser.add_argument("--gpu-image-ms", type=float, default=None, help="ms per image measured on your GPU")
    parser.add_argument("--gpu-pair-ms", type=float, default=None, help="ms per GV pair measured on your GPU")
    parser.add_argument("--no-ray", action="store_true", help="do not measure Ray's start-up")
    return parser.parse_args(argv)


def input_pixels(spec) -> int:
    size = spec.preprocessing.image_size
    return NATIVE_PIXELS if size is None else size[0] * size[1]


def measure_extraction(paths: list[Path], repeats: int) -> float:
    """Median seconds per image of the offline default model, end to end from JPEG files."""
    model = load_model(DEFAULT_MODEL)
    extract_descriptors(model, paths[:16], progress=False)  # warm-up: first-call allocations
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        extract_descriptors(model, paths, batch_size=16, progress=False)
        runs.append((time.perf_counter() - start) / len(paths))
    return statistics.median(runs)


def measure_search(repeats: int, n_database: int = 20_000, n_queries: int = 1_000, dim: int = 512) -> float:
    """Median seconds per multiply-add of an exact Faiss inner-product search (k = 10)."""
    import faiss

    rng = np.random.default_rng(0)
    database = rng.standard_normal((n_database, dim), dtype=np.float32)
    queries = rng.standard_normal((n_queries, dim), dtype=np.float32)
    index = faiss.IndexFlatIP(dim)
    index.add(database)
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        index.search(queries, 10)
        runs.append((time.perf_counter() - start) / (n_database * n_queries * dim))
    return statistics.median(runs)


def measure_su(repeats: int) -> float:
    """Median seconds per query of SU on (100,000, 10) scores."""
    from vpr_uncertainty import statistical_uncertainty

    scores = -np.sort(-np.random.default_rng(0).random((100_000, 10)), axis=1)
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        statistical_uncertainty(scores, k=10)
        runs.append((time.perf_counter() - start) / len(scores))
    return statistics.median(runs)


def measure_gv(data: Path, methods: str, pairs: int, repeats: int, folder: Path) -> dict[str, tuple[float, float]]:
    """Median (seconds per pair for matching + RANSAC, seconds per image for local features) of each GV method.

    The pairs are the first corridor queries and their NetVLAD top-1 matches, on 640-pixel copies; no feature cache,
    so every run extracts the features of every image it needs; all cores (the verifier's default threads).
    """
    from vpr_uncertainty import read_results
    from vpr_uncertainty.geometric import GeometricVerifier

    corridor = data / "vprbench" / "corridor"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy files are pickles and say so
        retrieval = read_results(
            data / "vprbench" / "precomputed_matches" / "corridor" / "NetVLAD" / "precomputed_data_corrected.npy",
            ground_truth=corridor / "ground_truth_new.npy",
        )
    queries = resized_copies(sorted((corridor / "query").glob("*.jpg"))[:pairs], 640, folder / "gv")
    database = resized_copies(sorted((corridor / "ref").glob("*.jpg")), 640, folder / "gv")
    top1 = np.stack([np.arange(len(queries)), retrieval.indices[: len(queries), 0]], axis=1)
    costs = {}
    for name in (name.strip() for name in methods.split(",") if name.strip()):
        verifier = GeometricVerifier.from_preset(name)
        verifier.verify(queries[:1], database, top1[:1])  # warm-up: first-call allocations
        per_pair, per_image = [], []
        for _ in range(repeats):
            result = verifier.verify(queries, database, top1)
            per_pair.append((result.matching_seconds + result.ransac_seconds) / len(top1))
            per_image.append(result.extraction.seconds / result.extraction.extracted)
        costs[name] = (statistics.median(per_pair), statistics.median(per_image))
    return costs


def measure_ray_start() -> float:
    import ray

    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    start = time.perf_counter()
    ray.init(address="local", num_cpus=1, include_dashboard=False, log_to_driver=False)
    seconds = time.perf_counter() - start
    ray.shutdown()
    return seconds


def hours(seconds: float) -> str:
    return f"{seconds / 3600:,.1f}"


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.data is None:
        raise SystemExit("set VPR_UNCERTAINTY_DATA or pass --data")
    datasets = [get_named_dataset(name) for name in PAPER_DATASETS]
    corridor = sorted((Path(args.data) / "vprbench" / "corridor" / "ref").glob("*.jpg"))[: args.images]
    with tempfile.TemporaryDirectory(prefix="projection_") as folder:
        image_seconds = measure_extraction(resized_copies(corridor, 640, Path(folder) / "ref"), args.repeats)
        gv = measure_gv(Path(args.data), args.gv, args.pairs, args.repeats, Path(folder))
    mac_seconds = measure_search(args.repeats)
    su_seconds = measure_su(args.repeats)
    ray_start = 0.0 if args.no_ray else measure_ray_start()

    print(f"measured on this machine ({os.cpu_count()} CPUs), medians of {args.repeats}:")
    print(f"- extraction, offline EfficientNet-Lite0 at 640x480: {image_seconds * 1e3:.1f} ms per image")
    print(f"- exact Faiss search: {mac_seconds * 1e12:.1f} ps per multiply-add")
    print(f"- SU: {su_seconds * 1e9:.0f} ns per query")
    for name, (pair, image) in gv.items():
        print(f"- {name} at 640x480: {pair * 1e3:.1f} ms per pair (features cached), {image * 1e3:.1f} ms per image")
    print(f"- Ray start-up (ray.init, local cluster): {ray_start:.1f} s\n")

    images = sum(d.n_database + d.n_queries for d in datasets)
    queries = sum(d.n_queries for d in datasets)
    print("| dataset | database | queries |\n|---|---:|---:|")
    for d in datasets:
        print(f"| {d.title} | {d.n_database:,} | {d.n_queries:,} |")
    print(f"| total | {images - queries:,} | {queries:,} |\n")

    lite0 = GMACS_224["EfficientNet-Lite0"] * NATIVE_PIXELS / 224**2
    stages: list[tuple[str, int, float]] = []  # (stage, items, seconds of work)
    extraction = 0.0
    search = 0.0
    largest = (0.0, "", "")
    print("| method | backbone | input pixels | GMACs per image | estimated ms per image | hours, all images |")
    print("|---|---|---:|---:|---:|---:|")
    for spec in HUB_MODELS:
        gmacs = GMACS_224[spec.backbone] * input_pixels(spec) / 224**2
        extraction += images * image_seconds * gmacs / lite0
        print(
            f"| {spec.name} | {spec.backbone} | {input_pixels(spec):,} | {gmacs:.1f} | "
            f"{image_seconds * gmacs / lite0 * 1e3:,.0f} | {hours(images * image_seconds * gmacs / lite0)} |"
        )
        for d in datasets:
            search += d.n_queries * d.n_database * spec.descriptor_dim * mac_seconds
            size = d.n_database * spec.descriptor_dim * 4
            largest = max(largest, (size, spec.name, d.title))
    methods = len(HUB_MODELS)
    stages.append(
        ("extraction at the offline model's cost (lower bound)", methods * images, methods * images * image_seconds)
    )
    stages.append(("extraction, FLOPs-scaled to the nine backbones (estimate)", methods * images, extraction))
    stages.append(("exact retrieval (Faiss flat)", methods * queries, search))
    stages.append(("SU", methods * queries, methods * queries * su_seconds))
    for name, (pair, image) in gv.items():
        gv_images = sum(d.n_queries + min(d.n_database, methods * d.n_queries) for d in datasets)
        stages.append((f"{name}: local features (once per image)", gv_images, gv_images * image))
        stages.append((f"{name}: matching + RANSAC (query vs top-1)", methods * queries, methods * queries * pair))
    print(f"(EfficientNet-Lite0, measured: {lite0:.1f} GMACs, {image_seconds * 1e3:.0f} ms per image)\n")
    header = " | ".join(f"{n} workers, h" for n in args.workers)
    print(f"| stage ({methods} methods x {len(datasets)} datasets) | items | one machine, h | {header} |")
    print("|---|---:|---:|" + "---:|" * len(args.workers))
    for stage, items, seconds in stages:
        spread = " | ".join(hours(seconds / n + ray_start) for n in args.workers)
        print(f"| {stage} | {items:,} | {hours(seconds)} | {spread} |")
    print(f"\nlargest database: {largest[1]} on {largest[2]}, {largest[0] / 2**30:.1f} GiB of float32 descriptors")
    if args.gpu_image_ms is not None or args.gpu_pair_ms is not None:
        print("\nGPU projection from the per-item costs given:")
        for label, items, ms in (
            ("extraction", methods * images, args.gpu_image_ms),
            ("GV pairs", methods * queries, args.gpu_pair_ms),
        ):
            if ms is not None:
                spread = ", ".join(f"{n} GPUs {hours(items * ms / 1e3 / n + ray_start)} h" for n in args.workers)
                print(f"- {label}: {items:,} x {ms} ms = {hours(items * ms / 1e3)} h on one GPU; {spread}")


if __name__ == "__main__":
    start = time.perf_counter()
    main()
    print(f"\n({time.perf_counter() - start:.0f} s)")
