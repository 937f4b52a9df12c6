"""How long a linkage's symbolic derivation takes: a benchmark that prints, not a test (machines
differ, so nothing here is asserted; it was tests/test_linkage.py::test_cold_derivation_time,
which asserted nothing).

    python tests/derivation_time.py

Prints, for the planar 3-link arm in a fresh process: the import of stw_tui.sym.linkage, its
first (cold) derivation, and a second one of the same structure under other names; then, in this
process, the derivation of the 3-D creature of tests/test_linkage.py (a moving, turning base and
three twisted links, 6 DOF).
"""

import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]

COLD = (
    "import time; t0 = time.perf_counter();"
    "from stw_tui.sym.linkage import parse_linkage, derive; t1 = time.perf_counter();"
    "spec = parse_linkage('linkage arm', [(2, 'SHOULDER revolute a=0.35 mass=2'),"
    " (3, 'ELBOW revolute a=0.3 mass=1.5'), (4, 'WRIST revolute a=0.15 mass=0.5')]);"
    "d = derive(spec); t2 = time.perf_counter();"
    "spec2 = parse_linkage('linkage arm2', [(2, 'A revolute a=0.35 mass=2'),"
    " (3, 'B revolute a=0.3 mass=1.5'), (4, 'C revolute a=0.15 mass=0.5')]);"
    "derive(spec2); t3 = time.perf_counter();"
    "print(f'import {t1-t0:.3f} s, cold derive {t2-t1:.3f} s, second derive {t3-t2:.3f} s')"
)


def main() -> None:
    out = subprocess.run([sys.executable, "-c", COLD], capture_output=True, text=True, check=True, cwd=ROOT)
    print("3-link arm:", out.stdout.strip())
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    from test_linkage import SPATIAL, make

    from stw_tui.sym.linkage import derive

    start = time.perf_counter()
    derive(make(SPATIAL))
    print(f"3-D creature (6 DOF) derive: {time.perf_counter() - start:.3f} s")


if __name__ == "__main__":
    main()
