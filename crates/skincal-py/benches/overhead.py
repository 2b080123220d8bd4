"""The Python layer's overhead on `calibrate`: the package's call against the library call timed
in Rust, on the same data (the humanoid with default noise, unless a measurement set is given).

    python crates/skincal-py/benches/overhead.py [measurements.json] [--repeats N]
"""

import argparse
import statistics
import time

import skincal
from skincal import _skincal


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("measurements", nargs="?")
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    if args.measurements:
        data, name = skincal.MeasurementSet.load(args.measurements), args.measurements
    else:
        data, name = skincal.simulate("humanoid"), "humanoid (simulate defaults)"
    structure = skincal.explore(data)
    python = []
    for _ in range(args.repeats):
        started = time.perf_counter()
        model = skincal.calibrate(data, structure)
        python.append(time.perf_counter() - started)
    library = _skincal.bench_calibrate(data._native, structure._native, args.repeats)
    py = statistics.median(python)
    print(f"calibrate {name}: {len(data.sus)} SUs, {len(data.dofs)} DoFs, {len(model.limbs)} limbs")
    print(f"{'':24}{'median':>10}")
    print(f"{'library (Rust)':24}{library * 1e3:>8.1f} ms")
    print(f"{'skincal.calibrate':24}{py * 1e3:>8.1f} ms")
    print(f"{'overhead':24}{(py / library - 1) * 100:>8.1f} %")


if __name__ == "__main__":
    main()
