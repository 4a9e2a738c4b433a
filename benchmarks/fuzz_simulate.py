"""`dynamics simulate` on valid but extreme scenes (issue 12, item 3), plus the reproducers.

Scenes are drawn with hypothesis from valid ranges stretched to extremes (speeds up to
10 km/s, spins up to 1e6 rad/s, friction 0..20, masses 1 mg..1000 t, overlapping placements,
objects below the floor, high frame rates, long durations) and each is run through
``pipeline.cli.main(["simulate", ...])`` at 32 x 32 px. Each run must end with exit 0 and pass
every check, or exit 2 with one stderr line; a traceback (any other exception), exit 1 or a
run over ``--timeout`` seconds is a failure. Writes ``reports/fuzz_simulate.json`` with the
outcome counts, the checks that refused scenes and the reproducers' outcomes.

    MUJOCO_GL=egl python benchmarks/fuzz_simulate.py --examples 250
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import shutil
import signal
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.atomic import write_json  # noqa: E402

REPRO = ROOT.parent / "shared" / "repro"

extreme = st.sampled_from([0.0, 1e-3, 0.5, 2.0, 10.0, 100.0, 1e3, 1e4])
spin = st.sampled_from([0.0, 1.0, 30.0, 1e3, 1e6])


@st.composite
def scenes(draw) -> str:
    """A valid scene text with extreme values."""
    n = draw(st.integers(1, 4))
    objects = []
    for i in range(n):
        shape = draw(st.sampled_from(["sphere", "box", "cylinder"]))
        s = draw(st.sampled_from([0.01, 0.1, 0.3]))
        size = {"sphere": {"radius": s}, "box": {"width": s, "depth": s, "height": s},
                "cylinder": {"radius": s, "height": s}}[shape]
        rest = s / 2 if shape != "sphere" else s          # resting on the floor
        z = draw(st.sampled_from([rest, rest, rest, s * 3, 5.0, -0.2]))   # 1 in 6 starts in the floor
        x = draw(st.sampled_from([i - 1.5, i - 1.5, i - 1.5, 0.05 * i]))  # 1 in 4 may overlap another
        objects.append({
            "shape": shape, "size": size, "mass": draw(st.sampled_from([1e-6, 0.01, 1.0, 100.0, 1e6])),
            "position": [x, 0.3, z],
            "linear_velocity": [draw(extreme) * draw(st.sampled_from([-1, 1])), 0.0, draw(extreme) * -1],
            "angular_velocity": [0.0, draw(spin), draw(spin)],
            "material": {"sliding_friction": draw(st.sampled_from([0.0, 0.1, 0.5, 2.0, 10.0, 20.0])),
                         "rolling_friction": draw(st.sampled_from([0.0, 0.01, 1.0])),
                         "damping": draw(st.sampled_from([0.0, 0.1, 10.0, 1e3]))}})
    fps = draw(st.sampled_from([1, 24, 30, 60, 240, 1000]))
    duration = draw(st.sampled_from([0.1, 0.5, 1.0]))
    doc = {"duration": duration, "fps": fps, "gravity": draw(st.sampled_from([0.0, 9.81, 100.0, 1e4])),
           "camera": {"height": 1.2}, "objects": objects}
    return yaml.safe_dump(doc)


class _Timeout(Exception):
    pass


def run_one(scene_path: Path, out: Path, timeout: float, *extra: str) -> tuple[str, str]:
    """Run `dynamics simulate` in process; returns ``(outcome, detail)``: ``ok``,
    ``error:<check>``, ``failure:traceback``, ``failure:exit<rc>``, ``failure:message`` or
    ``failure:timeout``."""
    from pipeline.cli import main

    shutil.rmtree(out, ignore_errors=True)
    err = io.StringIO()

    def alarm(*_):
        raise _Timeout()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main(["simulate", str(scene_path), "--out", str(out), "--width", "32", "--height", "32", *extra])
    except _Timeout:
        return "failure:timeout", ""
    except Exception as exc:  # noqa: BLE001 - what we look for
        return "failure:traceback", f"{type(exc).__name__}: {str(exc)[:200]}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    text = "\n".join(line for line in err.getvalue().splitlines() if not line.startswith("warning:"))
    if rc == 0:
        return "ok", ""
    if rc != 2:
        return f"failure:exit{rc}", text[:300]
    if text.count("\n") != 0 or len(text) > 400 or not text:
        return "failure:message", text[:400]
    m = re.search(r": (simulation(?:\.\w+)?|objects|duration \* fps|[\w\[\].]+): must", text)
    return f"error:{m.group(1) if m else 'other'}", text


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=250)
    parser.add_argument("--timeout", type=float, default=60.0, help="s per run")
    parser.add_argument("--out", type=Path, default=ROOT / "reports" / "fuzz_simulate.json")
    args = parser.parse_args()
    try:
        from absl import logging as absl_logging

        absl_logging.set_verbosity(absl_logging.ERROR)
    except ImportError:  # pragma: no cover
        pass
    counts: Counter[str] = Counter()
    failures: list[dict] = []
    slowest = [0.0, ""]
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene_path, out = tmp / "scene.yaml", tmp / "out"

        @settings(max_examples=args.examples, deadline=None, database=None, derandomize=True,
                  suppress_health_check=list(HealthCheck))
        @given(scenes())
        def one(text: str) -> None:
            scene_path.write_text(text)
            t = time.perf_counter()
            outcome, detail = run_one(scene_path, out, args.timeout)
            dt = time.perf_counter() - t
            counts[outcome] += 1
            if dt > slowest[0]:
                slowest[:] = [dt, outcome]
            if outcome.startswith("failure") and len(failures) < 20:
                failures.append({"outcome": outcome, "detail": detail, "scene": text})

        one()
        repro = {}
        for f in sorted(REPRO.glob("scene_*.yaml")):
            outcome, detail = run_one(f, out, args.timeout)
            repro[f.name] = {"outcome": outcome, "message": detail}
    report = {"runs": sum(counts.values()), "outcomes": dict(sorted(counts.items())),
              "failures": sum(v for k, v in counts.items() if k.startswith("failure")),
              "slowest_s": round(slowest[0], 2), "slowest_outcome": slowest[1],
              "seconds": round(time.time() - t0, 1), "reproducers": repro, "failure_examples": failures}
    write_json(args.out, report)
    print(json.dumps({k: v for k, v in report.items() if k not in ("failure_examples", "reproducers")}, indent=2))
    for name, r in repro.items():
        print(f"{name}: {r['outcome']}")
    for f in failures[:5]:
        print(f)
    return 1 if report["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
