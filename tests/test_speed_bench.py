"""The speed benchmark command runs end to end on tiny sizes and writes its JSON."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_speed_quick_json_shape(tmp_path):
    out = tmp_path / "speed.json"
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "speed.py"), "--quick", "--repeat", "2",
                        "--threads", "1", "--json", str(out)], capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["benchmark"] == "speed" and doc["quick"] is True and doc["repeat"] == 2
    assert doc["trees"] == ["current"]
    assert str(tmp_path) not in json.dumps(doc)          # no local paths
    assert {"cpu", "cores", "python", "numba"} <= set(doc["machine"])
    jobs = {r["job"]: r for r in doc["rows"]}
    assert set(jobs) == {"octet", "png", "micro", "jelly", "jelly2x", "render_micro", "render_jelly", "ctb"}
    for r in doc["rows"]:
        assert r["tree"] == "current" and r["threads"] == 1
        assert len(r["runs_seconds"]) == 2 and all(s > 0 for s in r["runs_seconds"])
        assert min(r["runs_seconds"]) <= r["median_seconds"] <= max(r["runs_seconds"])
    for job in ("octet", "micro", "jelly", "jelly2x", "render_micro", "render_jelly", "ctb"):
        assert jobs[job]["evaluations"] > 0, job
    # the evaluation count does not depend on the run
    assert "evaluations_vary" not in jobs["micro"]
    # doubling the layers of the same trace adds layers, not crossings: more work, less than twice
    assert jobs["jelly"]["evaluations"] < jobs["jelly2x"]["evaluations"] < 2 * jobs["jelly"]["evaluations"]
    # the table is printed with one row per job
    assert p.stdout.count("\n| ") >= 6 and "| octet |" in p.stdout
