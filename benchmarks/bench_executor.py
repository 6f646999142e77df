"""Extraction throughput with the local executor and with Ray at 1 and 2 workers, and Ray's start-up overhead.

On the 222 corridor images (111 database + 111 query) with the offline default model, batch size 16, each run into
a fresh HDF5 file. ``local`` is the in-process extraction as ``extract`` runs it (torch's default threads, image
decoding threads); ``ray N`` starts a local Ray cluster of N CPUs and a pool of N model actors (one model load each,
one torch thread each), counted in its time. Start-up is measured separately: ``ray.init`` of a local cluster, and
the first actor's model load. Prints a Markdown table; on a machine with C cores expect scaling only up to C.

    python benchmarks/bench_executor.py                  # VPR_UNCERTAINTY_DATA must point at the shared data
    python benchmarks/bench_executor.py --workers 1 2 4
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from vpr_uncertainty.executors import get_executor
from vpr_uncertainty.stages.descriptors import DescriptorsConfig, extract


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=os.environ.get("VPR_UNCERTAINTY_DATA"), help="shared data folder")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="Ray worker counts (default 1 2)")
    parser.add_argument("--batch-size", type=int, default=16)
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
        extract(
            DescriptorsConfig(batch_size=batch_size, progress=False), images, Path(folder) / "d.h5", executor=executor
        )
        return time.perf_counter() - start


def startup_seconds() -> tuple[float, float]:
    """(ray.init of a local 1-CPU cluster, the first actor's model load) in seconds."""
    import ray

    from vpr_uncertainty.descriptors.distributed import DescriptorActor
    from vpr_uncertainty.stages.descriptors import model_of

    start = time.perf_counter()
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    init = time.perf_counter() - start
    from functools import partial

    start = time.perf_counter()
    actor = ray.remote(DescriptorActor).options(num_cpus=1).remote(partial(model_of, DescriptorsConfig()))
    ray.get(actor.pid.remote())
    load = time.perf_counter() - start
    ray.shutdown()
    return init, load


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.data is None:
        raise SystemExit("set VPR_UNCERTAINTY_DATA or pass --data")
    images = corridor_images(args.data)
    count = sum(len(names) for _, names in images.values())
    init, load = startup_seconds()
    rows = [("local", timed_extraction(images, args.batch_size))]
    for workers in args.workers:
        start = time.perf_counter()
        with get_executor("ray", workers=workers) as executor:
            timed_extraction(images, args.batch_size, executor)
        rows.append((f"ray {workers}", time.perf_counter() - start))
    print(f"{count} corridor images, batch size {args.batch_size}, {os.cpu_count()} CPUs\n")
    print("| executor | seconds (incl. Ray start) | images/s | vs local |")
    print("|---|---:|---:|---:|")
    for name, seconds in rows:
        print(f"| {name} | {seconds:.1f} | {count / seconds:.1f} | {rows[0][1] / seconds:.2f}x |")
    print(f"\nRay start-up: ray.init of a local cluster {init:.1f} s; first actor with its model loaded {load:.1f} s")


if __name__ == "__main__":
    main()
