"""What building the C++ core costs: wall time, CPU time and the largest compiler process.

    python benchmarks/bench_build.py [--source DIR] [--build DIR] [--jobs 2] [--no-python] [-D NAME=VALUE ...]

Configures a fresh build directory (Release, tests on, the Python module on unless --no-python,
warnings as errors as CI builds), then builds with ``-j JOBS`` in two phases: the core library
and its ctest suite (the target ``gpsins_cpp_tests``), then everything else (the module). Every
compile and link runs under this script as CMake's compiler and linker launcher, which records
the process's own CPU time and largest resident set (``wait4``'s rusage: the compiler driver and
the cc1plus / as / lto1 processes it ran). Prints, per phase and in all, wall time, CPU time and
the load average, and the ten largest processes by memory and by CPU. It only reports figures:
it asserts nothing. The machine's load during the build counts in the wall time: compare runs
made under the same load.

``--source`` builds another checkout (e.g. ``git archive`` of an older commit) with its own
CMakeLists; ``-D`` passes cache entries (``-D GPSINS_FILTER_OPT=-O3``).
"""

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def launch(argv: list[str]) -> int:
    """Launcher mode: ``bench_build.py --launch LOG COMMAND...``: run COMMAND, append its rusage to LOG."""
    log, cmd = argv[0], argv[1:]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    out = cmd[cmd.index("-o") + 1] if "-o" in cmd else cmd[-1]
    with open(log, "a") as f:
        f.write(json.dumps({"out": out, "wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime,
                            "maxrss_mb": ru.ru_maxrss / 1024}) + "\n")
    return os.waitstatus_to_exitcode(status)


def python_cmake_options() -> list[str]:
    py = sys.executable
    pybind = subprocess.run([py, "-m", "pybind11", "--cmakedir"], capture_output=True, text=True, check=True)
    return [f"-DPython_EXECUTABLE={py}", f"-Dpybind11_DIR={pybind.stdout.strip()}"]


def phase(build: Path, target: str | None, jobs: int, log: Path) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = log.stat().st_size if log.exists() else 0
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    cmd = ["cmake", "--build", str(build), "-j", str(jobs)] + (["--target", target] if target else [])
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    with open(log) as f:
        f.seek(start)
        rows = [json.loads(line) for line in f if line.strip()]
    return {"wall_s": wall, "cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
            "load_before": load0, "load_1min_after": os.getloadavg()[0], "rows": rows}


def show(name: str, ph: dict) -> None:
    rows = ph["rows"]
    peak = max(rows, key=lambda r: r["maxrss_mb"]) if rows else None
    print(f"{name}: wall {ph['wall_s'] / 60:.2f} min, CPU {ph['cpu_s'] / 60:.2f} min, {len(rows)} processes, "
          f"largest {peak['maxrss_mb']:.0f} MB ({Path(peak['out']).name}); load average before "
          f"{ph['load_before']:.2f}, 1-min after {ph['load_1min_after']:.2f}" if peak else f"{name}: nothing built")


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--launch":
        return launch(sys.argv[2:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", default=str(ROOT), help="the checkout to build (default: this one)")
    ap.add_argument("--build", help="build directory, removed first (default: SOURCE/build/bench)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-python", action="store_true", help="core and ctest suite only")
    ap.add_argument("-D", dest="defs", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args()
    src = Path(a.source).resolve()
    build = Path(a.build).resolve() if a.build else src / "build" / "bench"
    shutil.rmtree(build, ignore_errors=True)
    build.mkdir(parents=True)
    log = build / "rusage.jsonl"
    me = [sys.executable, str(Path(__file__).resolve()), "--launch", str(log)]
    launcher = ";".join(me)
    cfg = ["cmake", "-S", str(src), "-B", str(build), "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
           "-DGPSINS_BUILD_TESTS=ON", f"-DGPSINS_BUILD_PYTHON={'OFF' if a.no_python else 'ON'}",
           "-DGPSINS_WERROR=ON", f"-DCMAKE_CXX_COMPILER_LAUNCHER={launcher}",
           f"-DCMAKE_CXX_LINKER_LAUNCHER={launcher}"] + [f"-D{d}" for d in a.defs]
    if not a.no_python:
        cfg += python_cmake_options()
    t0 = time.perf_counter()
    subprocess.run(cfg, check=True, stdout=subprocess.DEVNULL)
    print(f"configure: {time.perf_counter() - t0:.1f} s; {os.cpu_count()} cores, -j {a.jobs}; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    phases = [("core + ctest suite", phase(build, "gpsins_cpp_tests", a.jobs, log))]
    if not a.no_python:
        phases.append(("the rest (Python module)", phase(build, None, a.jobs, log)))
    for name, ph in phases:
        show(name, ph)
    rows = [r for _, ph in phases for r in ph["rows"]]
    total = {"wall_s": sum(ph["wall_s"] for _, ph in phases), "cpu_s": sum(ph["cpu_s"] for _, ph in phases),
             "load_before": phases[0][1]["load_before"], "load_1min_after": phases[-1][1]["load_1min_after"],
             "rows": rows}
    show("all", total)
    print("largest by memory:")
    for r in sorted(rows, key=lambda r: -r["maxrss_mb"])[:10]:
        print(f"  {r['maxrss_mb']:7.0f} MB  {r['cpu_s']:6.1f} s CPU  {Path(r['out']).name}")
    print("largest by CPU:")
    for r in sorted(rows, key=lambda r: -r["cpu_s"])[:10]:
        print(f"  {r['cpu_s']:6.1f} s CPU  {r['maxrss_mb']:7.0f} MB  {Path(r['out']).name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
