"""The speed benchmark command runs end to end on tiny sizes and writes its JSON."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

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


def test_kernel_profile_names_numba_symbols_and_sums_their_shares():
    """benchmarks/kernel_profile.py reads ``perf report --sort sym --stdio``: Numba's
    mangled names of slicer._kernels become ``module.function``, specialisations of
    one function add up, other symbols (the interpreter, LLVM compiling) are left out
    of the shares but not of the total."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("kernel_profile", ROOT / "benchmarks" / "kernel_profile.py")
    kp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(kp)
    assert kp.kernel_name("_ZN6slicer8_kernels5trace18trace_ray_intervalB3v20B56c8tJTIeFIjxB2IKSgI4CrvQCk0Z") \
        == "trace.trace_ray_interval"
    assert kp.kernel_name("_ZN5numba7cpython8unicodeE") is None and kp.kernel_name("_PyEval_EvalFrameDefault") is None
    assert kp.kernel_name("NRT_incref") == "NRT_incref"
    report = """# Samples: 15K of event 'cpu-clock:ppp'
#
    60.00%  [.] _PyEval_EvalFrameDefault
     3.00%  [.] _ZN6slicer8_kernels5field12segment_evalB3v63B56c8tJTIeFIjxB2IKSgI4CrvSCKg1MMbCQQ
     1.00%  [.] _ZN6slicer8_kernels5field12segment_evalB3v64B56c8tJTIeFIjxB2IKSgI4CrvSCKg1MMbCQQ
     4.00%  [.] _ZN6slicer8_kernels5trace18trace_ray_intervalB3v20B56c8tJTIeFIjxB2IKSgI4CrvQCk0Z
     2.00%  NRT_decref
"""
    shares, jit = kp.kernel_shares(report)
    assert list(shares) == ["field.segment_eval", "trace.trace_ray_interval", "NRT_decref"]
    assert shares["field.segment_eval"] == pytest.approx(0.4) and shares["NRT_decref"] == pytest.approx(0.2)
    assert jit == pytest.approx(0.10)
    assert kp.kernel_shares("nothing here") == ({}, 0.0)


def test_bucket_size_benchmark_compares_edges_on_the_same_layers(tmp_path):
    """``benchmarks/bucket_size.py --quick`` traces every job at every edge, checks the
    layers do not depend on it (the evaluations neither) and writes its JSON."""
    out = tmp_path / "bucket.json"
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bucket_size.py"), "--quick", "--repeat", "2",
                        "--threads", "1", "--buckets", "64", "16", "--json", str(out)],
                       capture_output=True, text=True, encoding="utf-8", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["benchmark"] == "bucket_size" and doc["quick"] is True and doc["repeat"] == 2
    assert str(tmp_path) not in json.dumps(doc)
    rows = doc["rows"]
    assert [(r["job"], r["bucket"]) for r in rows] == [(j, b) for j in ("jelly", "micro", "octet") for b in (64, 16)]
    for j in ("jelly", "micro", "octet"):
        ev = {r["evaluations"] for r in rows if r["job"] == j}
        assert len(ev) == 1 and ev.pop() > 0, j
    for r in rows:
        assert len(r["runs_seconds"]) == 2 and min(r["runs_seconds"]) <= r["median_seconds"] <= max(r["runs_seconds"])
    assert p.stdout.count("\n| ") >= 7


def test_bucket_size_benchmark_refuses_a_bad_edge(tmp_path):
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bucket_size.py"), "--quick", "--buckets", "0"],
                       capture_output=True, text=True, encoding="utf-8", cwd=tmp_path)
    assert p.returncode == 2 and "must be >= 1" in p.stderr


def test_speed_benchmark_byte_compiles_each_tree(tmp_path):
    """Every tree is timed as an installed package runs: its packages' bytecode is
    written before timing (so no run compiles Python sources, even under
    PYTHONDONTWRITEBYTECODE), and a tree whose source does not compile is refused."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("speed_bench", ROOT / "benchmarks" / "speed.py")
    sb = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sb)
    tree = tmp_path / "tree"
    (tree / "slicer" / "sub").mkdir(parents=True)
    (tree / "slicer" / "a.py").write_text("X = 1\n")
    (tree / "slicer" / "sub" / "b.py").write_text("Y = 2\n")
    (tree / "formats").mkdir()
    (tree / "formats" / "c.py").write_text("Z = 3\n")
    (tree / "other").mkdir()
    (tree / "other" / "d.py").write_text("W = 4\n")
    assert sb.byte_compile(tree)
    tag = sys.implementation.cache_tag
    for f in ("slicer/a.py", "slicer/sub/b.py", "formats/c.py"):
        src = tree / f
        assert (src.parent / "__pycache__" / f"{src.stem}.{tag}.pyc").is_file(), f
    assert not (tree / "other" / "__pycache__").exists()     # not one of the packages the jobs import
    (tree / "formats" / "bad.py").write_text("def (:\n")
    assert not sb.byte_compile(tree)


# --------------------------------------------------------------------------- benchmarks/compile_time.py
def _compile_time_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("compile_time", ROOT / "benchmarks" / "compile_time.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("args, needle", [
    (["--repeat", "0"], "--repeat must be >= 1"),
    (["--baseline", "."], "no slicer package there"),
    (["--jobs", "rendering"], "invalid choice"),
    (["--kernels", "-1"], "--kernels >= 0"),
])
def test_compile_time_refuses_bad_arguments_before_compiling_anything(tmp_path, args, needle):
    """Through the real entry point: a usage error (exit 2) naming the problem,
    and no run started (a run would take a minute of compiling)."""
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "compile_time.py"), *args], capture_output=True,
                       text=True, cwd=tmp_path, timeout=60)
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert needle in p.stderr and "Traceback" not in p.stderr
    assert "run 1" not in p.stderr


def test_compile_time_alternates_trees_with_a_fresh_cache_each_and_reports_medians(tmp_path, monkeypatch):
    """The driver's bookkeeping with the subprocess replaced: every (job, tree)
    runs ``repeat`` times, trees alternating within a round; each cold run gets
    an empty cache folder of its own and the warm run reuses it; compile is
    first minus steady; the medians and the table follow."""
    ct = _compile_time_module()
    monkeypatch.setattr(ct, "byte_compile", lambda tree: True)
    calls = []
    fake = {("contours", "a"): [(10.0, 1.0), (14.0, 2.0), (12.0, 1.0)], ("contours", "b"): [(20.0, 1.0),
                                                                                           (30.0, 1.0), (25.0, 3.0)]}
    seen_caches = []

    def run(job, tree, cache):
        calls.append((job, tree.name))
        k = sum(1 for c in calls if c == (job, tree.name)) - 1
        if k % 2 == 0:                      # the cold run: its cache folder is new and empty
            assert cache not in seen_caches and not any(cache.iterdir())
            seen_caches.append(cache)
            first, steady = fake[(job, tree.name)][k // 2]
        else:                               # the warm run: the same folder as the cold one
            assert cache == seen_caches[-1]
            first, steady = 0.25 + k, 0.0
        # the kernels' own compile seconds: one kernel takes the whole first call, another a second
        return {"first_seconds": first, "steady_seconds": steady, "kernels": {"m.f": first - steady, "m.g": 1.0}}

    monkeypatch.setattr(ct, "_run", run)
    trees = {"a": tmp_path / "a", "b": tmp_path / "b"}
    rows = ct.measure(trees, ["contours"], 3, log=lambda s: None)
    assert [c[1] for c in calls] == ["a", "a", "b", "b"] * 3
    by = {r["tree"]: r for r in rows}
    assert [r["compile_seconds"] for r in by["a"]["runs"]] == [9.0, 12.0, 11.0]
    assert by["a"]["median_compile_seconds"] == 11.0 and by["b"]["median_compile_seconds"] == 22.0
    assert by["a"]["median_first_seconds"] == 12.0 and by["b"]["median_first_seconds"] == 25.0
    assert by["a"]["median_cached_seconds"] == 3.25
    text = ct.table(rows, ["a", "b"])
    assert "| contours | 11.0 s | 22.0 s | 3.25 s | 3.25 s |" in text
    assert by["b"]["median_kernel_seconds"] == {"m.f": 22.0, "m.g": 1.0}        # medians per kernel, longest first
    assert "| contours | `m.f` | 11.0 s | 100 % |" in ct.kernel_table(rows, "a", 5)


def test_coherence_model_quick_classifies_as_the_tracer(tmp_path):
    """benchmarks/coherence_model.py --quick: its modelled walks classify every centre as the
    tracer does (the script fails otherwise), the floor is below every walk, and the JSON
    holds the counts and no local path."""
    out = tmp_path / "coherence.json"
    p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "coherence_model.py"), "--quick", "--repeat", "1",
                        "--json", str(out)], capture_output=True, text=True, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    doc = json.loads(out.read_text())
    assert doc["benchmark"] == "coherence_model" and doc["quick"] is True
    assert str(tmp_path) not in json.dumps(doc)
    (w,) = doc["windows"]
    assert w["mismatched_columns"] == 0 and w["crossings"] > 0
    assert 0 < w["floor"] <= min(w["today"], w["bounds"], w["coherent"])
    assert w["coherent"] <= w["bounds"]             # the neighbour's crossings never cost evaluations here
    assert w["boxes_inside"] == w["today_inside"]   # the box model classifies the same centres
    assert "| coherent: neighbour's crossings first |" in p.stdout
