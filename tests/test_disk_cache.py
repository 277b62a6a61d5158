"""The disk cache of compiled problems across processes (model/cache.py):
IPOPT's derivative functions and the active-set step's Clarabel data are
loaded instead of built, give the very same answers, are found only by the
problem they were built for, and the folder stays under its size cap."""

from __future__ import annotations

import os
import pickle
import shutil
import subprocess
import sys
import time

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.methods import nlp_compiled, nlp_engine
from belief_nlp.model import cache as cache_mod
from belief_nlp.model.cache import MEMORY, DiskCache, disk_cache, set_disk_cache
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import build_nlp

from conftest import paper_multi_path_pair


@pytest.fixture
def small():
    return paper_multi_path_pair(steps_per_segment=2)          # K = 10


@pytest.fixture
def fresh():
    """Memory caches empty (as in a new process) and the process's disk
    cache setting restored afterwards."""
    saved = dict(cache_mod._DISK)
    env = {name: os.environ.get(name) for name in (cache_mod.ENV_DIR, cache_mod.ENV_COMPILE)}
    nlp_engine.clear_cache()
    MEMORY.clear()
    yield
    cache_mod._DISK.clear()
    cache_mod._DISK.update(saved)
    for name, value in env.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    nlp_engine.clear_cache()
    MEMORY.clear()


def _forget():
    nlp_engine.clear_cache()
    MEMORY.clear()


def test_a_second_process_loads_what_the_first_built_and_gets_the_same_answer(small, fresh, tmp_path):
    sc, path = small
    # (ccp_polish=10: auto's CCP polish runs, so its conic step is built, even at an answer stationary in S)
    set_disk_cache(False)
    reference = bn.smooth(sc, path, alpha=0.1, ccp_polish=10)                 # no disk cache at all
    _forget()
    folder = tmp_path / "cache"
    set_disk_cache(folder)
    first = bn.smooth(sc, path, alpha=0.1, ccp_polish=10)
    kinds = sorted(p.name.split(".")[1] for p in DiskCache(folder).entries())
    assert kinds == ["conic", "graph", "nlp"]
    assert all(oct(p.stat().st_mode & 0o777) == "0o600" for p in DiskCache(folder).entries())
    assert first.stats["ipopt"]["build"] == "built"
    _forget()                                                   # as a new process would start
    second = bn.smooth(sc, path, alpha=1.0, ccp_polish=10)                     # another alpha: the same entries serve it
    _forget()
    third = bn.smooth(sc, path, alpha=0.1, ccp_polish=10)
    assert second.stats["ipopt"]["build"] == third.stats["ipopt"]["build"] == "built (derivatives from disk)"
    for res in (first, third):
        assert res.safe and bn.verify(sc, res.path).safe
        assert res.cost == reference.cost and res.nit == reference.nit
        np.testing.assert_array_equal(res.path.x, reference.path.x)
        np.testing.assert_array_equal(res.path.S, reference.path.S)
    assert second.safe and second.cost <= second.initial_cost


def test_an_entry_is_found_only_by_the_problem_it_was_built_for(small, fresh, tmp_path):
    sc, path = small
    set_disk_cache(tmp_path)
    bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert len(DiskCache(tmp_path).entries()) == 2                 # the graph and its derivatives
    _forget()
    other = bn.smooth(sc, path, K=12, alpha=0.1, method="ipopt")     # another graph
    assert other.stats["build"] == "built" and other.safe
    _forget()
    reg = bn.smooth(sc, path, alpha=0.1, method="ipopt", regularisation=2e-4)   # another objective
    assert reg.stats["build"] == "built"
    assert len(DiskCache(tmp_path).entries()) == 6
    # the margin is in the rows' bounds, not the graph: the same derivatives
    # serve it, and the answer is the one built from scratch
    _forget()
    margin = bn.smooth(sc, path, alpha=0.1, method="ipopt", margin=2e-6)
    assert margin.stats["build"] == "built (derivatives from disk)"
    set_disk_cache(False)
    _forget()
    scratch = bn.smooth(sc, path, alpha=0.1, method="ipopt", margin=2e-6)
    assert scratch.stats["build"] == "built" and scratch.cost == margin.cost


def test_a_tampered_entry_is_rebuilt_not_loaded(small, fresh, tmp_path):
    sc, path = small
    set_disk_cache(tmp_path)
    first = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    (entry,) = [p for p in DiskCache(tmp_path).entries() if p.name.endswith(".nlp.pkl")]
    blob = bytearray(entry.read_bytes())
    blob[-10] ^= 0xFF
    entry.write_bytes(bytes(blob))
    _forget()
    again = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert again.stats["build"] == "built" and again.cost == first.cost


def test_an_nlp_rebuilt_from_its_stored_graph_is_the_same_function(small):
    sc, path = small
    model = BeliefModel(sc, 10, 0.3)
    fresh_nlp = build_nlp(model, "logchol")
    stored = pickle.loads(pickle.dumps(fresh_nlp.graph))           # as the disk cache keeps it
    again = build_nlp(model, "logchol", graph=stored)
    rng = np.random.default_rng(1)
    z = fresh_nlp.lbz.copy()
    z[~np.isfinite(z)] = 0.0
    z += rng.random(z.size)
    pv = np.concatenate([rng.random(fresh_nlp.p.numel() - 2), [0.3, 1.0]])
    fa = ca.Function("a", [fresh_nlp.z, fresh_nlp.p], [fresh_nlp.f, fresh_nlp.g])(z, pv)
    fb = ca.Function("b", [again.z, again.p], [again.f, again.g])(z, pv)
    for u, v in zip(fa, fb):
        np.testing.assert_array_equal(np.array(u), np.array(v))
    np.testing.assert_array_equal(fresh_nlp.lbg, again.lbg)
    np.testing.assert_array_equal(fresh_nlp.lbz, again.lbz)
    assert fresh_nlp.info == again.info
    np.testing.assert_array_equal(fresh_nlp.margin_values(z)[0], again.margin_values(z)[0])


def test_the_folder_stays_under_its_cap_and_keeps_recently_used_entries(tmp_path):
    disk = DiskCache(tmp_path, max_bytes=25_000)
    rng = np.random.default_rng(0)
    blobs = {name: rng.random(1000) for name in "abc"}           # ~8 kB each (random: incompressible)
    for i, name in enumerate("ab"):
        disk.save(name, blobs[name], kind="test")
        os.utime(tmp_path / f"{name}.test.pkl", (1e9 + i, 1e9 + i))   # a older than b
    assert disk.load("a", kind="test") is not None                     # a used now: b is the oldest
    disk.save("c", blobs["c"], kind="test")
    disk.save("d", blobs["a"], kind="test")
    names = sorted(p.name for p in disk.entries())
    assert "b.test.pkl" not in names and "d.test.pkl" in names
    assert sum(p.stat().st_size for p in disk.entries()) <= 25_000
    np.testing.assert_array_equal(disk.load("d", kind="test"), blobs["a"])


def test_the_environment_variable_switches_it_on_and_bad_settings_are_refused(fresh, tmp_path, monkeypatch):
    for value, expect in ((str(tmp_path), tmp_path), ("1", cache_mod.default_cache_dir()), ("0", None), ("", None)):
        monkeypatch.setenv(cache_mod.ENV_DIR, value)
        cache_mod._DISK.update(set=False, cache=None)
        got = disk_cache()
        assert (got is None) if expect is None else (got.dir == expect)
    with pytest.raises(ValidationError, match="where"):
        set_disk_cache(3)
    with pytest.raises(ValidationError, match="max_mb"):
        set_disk_cache(tmp_path, max_mb=0)
    assert set_disk_cache(None) is None and disk_cache() is None
    assert os.environ[cache_mod.ENV_DIR] == "0"


def test_the_derivative_key_is_the_same_in_a_fresh_process(small, fresh, tmp_path):
    """The entry's name is a hash of the graph's serialisation: a second
    process must build the identical graph, or every lookup would miss."""
    sc, path = small
    set_disk_cache(tmp_path)
    bn.smooth(sc, path, alpha=0.1, method="ipopt")
    # set_disk_cache also set BELIEF_NLP_CACHE_DIR: the child process finds the folder by it
    assert os.environ[cache_mod.ENV_DIR] == str(tmp_path.resolve())
    path_file = path.save(tmp_path / "path.json")
    code = ("import belief_nlp as bn;"
            f"print(bn.smooth('paper-multi', {str(path_file)!r}, alpha=0.1, method='ipopt').stats['build'])")
    env = {**os.environ, "PYTHONHASHSEED": "123"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "built (derivatives from disk)"


def test_the_cli_shows_and_clears_a_cache_folder(small, fresh, tmp_path, capsys):
    from belief_nlp.cli import EXIT_BAD_INPUT, EXIT_OK, main

    sc, path = small
    set_disk_cache(tmp_path)
    bn.smooth(sc, path, alpha=0.1, ccp_polish=10)             # the three kinds: graph, derivatives, conic step
    sizes = DiskCache(tmp_path).summary()
    assert main(["cache", "--dir", str(tmp_path)]) == EXIT_OK
    out = capsys.readouterr().out
    assert f"{tmp_path}: 3 entries" in out
    for kind, (n, _) in sizes.items():
        assert any(line.split()[:2] == [kind, str(n)] for line in out.splitlines()), (kind, out)
    assert main(["cache", "--dir", str(tmp_path), "--clear"]) == EXIT_OK
    assert "deleted 3 entries" in capsys.readouterr().out
    assert DiskCache(tmp_path).entries() == [] and (tmp_path / "hmac.key").exists()
    assert main(["cache", "--bogus"]) == EXIT_BAD_INPUT
    assert len(capsys.readouterr().err.strip().splitlines()) == 1



def test_the_scaled_stage_loads_its_derivatives_from_disk(small, fresh, tmp_path):
    """method "ipopt" with scale_means: the scaled stage's derivative functions
    are stored under the scaled graph's hash and a fresh process loads them."""
    sc, path = small
    set_disk_cache(tmp_path / "cache")
    first = bn.smooth(sc, path, method="ipopt", alpha=0.3, scale_means=100.0)
    _forget()
    second = bn.smooth(sc, path, method="ipopt", alpha=0.3, scale_means=100.0)
    assert first.stats["build"] == "built"
    assert second.stats["build"] == "built (derivatives from disk)"
    assert len([p for p in DiskCache(tmp_path / "cache").entries() if p.name.endswith(".nlp.pkl")]) == 2   # scaled, polish
    assert second.cost == first.cost and second.nit == first.nit and second.safe


# -- compiled derivative functions (methods/nlp_compiled.py) -------------------------------------------

needs_cc = pytest.mark.skipif(nlp_compiled.compiler() is None, reason="no C compiler on this machine")


@pytest.fixture
def tiny():
    return paper_multi_path_pair(steps_per_segment=1)          # K = 5: a few seconds of gcc


def _compiled_run(tiny, tmp_path, monkeypatch):
    """A first process with compilation on (the background build replaced by
    a record of its calls), then the library built in the foreground."""
    sc, path = tiny
    started = []
    monkeypatch.setattr(nlp_compiled, "start", lambda disk, name: started.append(name) or True)
    set_disk_cache(tmp_path, compile=True)
    first = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert first.stats["build"] == "built" and len(started) == 1
    lib = nlp_compiled.compile_entry(tmp_path, started[0])
    assert lib is not None and lib.exists() and oct(lib.stat().st_mode & 0o777) == "0o600"
    _forget()
    return started[0], first


@needs_cc
def test_compiled_derivatives_are_loaded_and_give_the_same_answers_bit_for_bit(tiny, fresh, tmp_path, monkeypatch):
    sc, path = tiny
    set_disk_cache(False)
    reference = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    _forget()
    name, first = _compiled_run(tiny, tmp_path, monkeypatch)
    assert sorted(DiskCache(tmp_path).summary()) == ["cso", "graph", "lib", "nlp"]
    again = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert again.stats["build"] == "built (derivatives compiled)"
    for res in (first, again):
        assert res.cost == reference.cost and res.nit == reference.nit and res.safe
        np.testing.assert_array_equal(res.path.x, reference.path.x)
        np.testing.assert_array_equal(res.path.S, reference.path.S)
    # each compiled function is the serialised one, bit for bit, at points of its own
    compiled = nlp_compiled.load(DiskCache(tmp_path), name)
    serialised = DiskCache(tmp_path).load(name, kind="nlp")
    rng = np.random.default_rng(5)
    for option, f in serialised.items():
        args = [rng.normal(size=f.nnz_in(i)) for i in range(f.n_in())]
        for u, v in zip(nlp_compiled._values(f, args), nlp_compiled._values(compiled[option], args)):
            np.testing.assert_array_equal(u, v)


@needs_cc
def test_a_library_other_than_the_signed_one_is_never_loaded(tiny, fresh, tmp_path, monkeypatch):
    sc, path = tiny
    name, first = _compiled_run(tiny, tmp_path, monkeypatch)
    disk = DiskCache(tmp_path)
    meta = disk.load(name, kind="cso")
    # values that the library does not reproduce (as from a miscompiled library): refused
    wrong = pickle.loads(pickle.dumps(meta))
    wrong["values"]["hess_lag"][0][0] += 1e-12
    disk.save(name, wrong, kind="cso")
    assert nlp_compiled.load(disk, name) is None
    disk.save(name, meta, kind="cso")
    assert nlp_compiled.load(disk, name) is not None
    # a changed library file: not the signed digest, never opened
    lib = tmp_path / f"{name}.lib.so"
    blob = bytearray(lib.read_bytes())
    blob[len(blob) // 2] ^= 0xFF
    lib.write_bytes(bytes(blob))
    assert nlp_compiled.load(disk, name) is None
    again = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert again.stats["build"] == "built (derivatives from disk)" and again.cost == first.cost


@needs_cc
def test_the_library_is_built_by_a_background_process(tiny, fresh, tmp_path):
    sc, path = tiny
    set_disk_cache(tmp_path, compile=True)
    assert os.environ[cache_mod.ENV_COMPILE] == "1"
    first = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert first.stats["build"] == "built"
    deadline = time.monotonic() + 240
    # done: the signed entry written, then (finally) its lock removed -- the
    # two are not one step, so wait for both (checking the lock right after
    # the entry appeared failed once under load)
    while (not any(p.name.endswith(".cso.pkl") for p in DiskCache(tmp_path).entries())
           or list(tmp_path.glob(".*.compiling"))):
        assert time.monotonic() < deadline, "the background build did not finish in 240 s"
        time.sleep(0.5)
    _forget()
    again = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert again.stats["build"] == "built (derivatives compiled)" and again.cost == first.cost


def test_without_a_compiler_nothing_is_started_and_settings_are_checked(fresh, tmp_path, monkeypatch):
    monkeypatch.setattr(nlp_compiled, "compiler", lambda: None)
    assert nlp_compiled.start(DiskCache(tmp_path), "x" * 40) is False
    assert not list(tmp_path.glob(".*"))
    with pytest.raises(ValidationError, match="compile"):
        set_disk_cache(False, compile=True)
    with pytest.raises(ValidationError, match="compile"):
        set_disk_cache(tmp_path, compile="yes")
    set_disk_cache(tmp_path)
    assert not cache_mod.compile_enabled() and os.environ[cache_mod.ENV_COMPILE] == "0"
    for value, expect in (("1", True), ("yes", True), ("0", False), ("", False), ("maybe", False)):
        monkeypatch.setenv(cache_mod.ENV_DIR, str(tmp_path))
        monkeypatch.setenv(cache_mod.ENV_COMPILE, value)
        cache_mod._DISK.update(set=False, cache=None)
        assert cache_mod.compile_enabled() is expect


def test_a_failing_compiler_is_recorded_and_not_run_again_by_every_process(tiny, fresh, tmp_path, monkeypatch):
    sc, path = tiny
    set_disk_cache(tmp_path)
    bn.smooth(sc, path, alpha=0.1, method="ipopt")                  # the serialised entry
    (entry,) = [p for p in DiskCache(tmp_path).entries() if p.name.endswith(".nlp.pkl")]
    name = entry.name.split(".")[0]
    false = shutil.which("false")
    if false is None:
        pytest.skip("no 'false' command to stand in for a failing compiler")
    monkeypatch.setenv("CC", false)
    lock = tmp_path / f".{name}.compiling"
    lock.touch()
    assert nlp_compiled._main([str(tmp_path), name, str(lock)]) == 1
    assert not lock.exists() and (tmp_path / f".{name}.failed").exists()
    assert nlp_compiled.start(DiskCache(tmp_path), name) is False      # not again for a day
    assert not lock.exists() and not list(tmp_path.glob("*.so"))


@needs_cc
def test_the_cli_compiles_every_entry_without_a_library(tiny, fresh, tmp_path, capsys):
    from belief_nlp.cli import EXIT_BAD_INPUT, EXIT_OK, main

    sc, path = tiny
    set_disk_cache(tmp_path)                                      # serialised entries only
    first = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    n = len(list(tmp_path.glob("*.nlp.pkl")))
    assert n >= 1 and not list(tmp_path.glob("*.so"))
    assert main(["cache", "--dir", str(tmp_path), "--compile", "--quiet"]) == EXIT_OK
    assert f"compiled {n} entries" in capsys.readouterr().out
    assert len(list(tmp_path.glob("*.lib.so"))) == n
    assert main(["cache", "--dir", str(tmp_path), "--compile", "--quiet"]) == EXIT_OK
    assert "compiled 0 entries" in capsys.readouterr().out
    set_disk_cache(tmp_path, compile=True)
    _forget()
    again = bn.smooth(sc, path, alpha=0.1, method="ipopt")
    assert again.stats["build"] == "built (derivatives compiled)" and again.cost == first.cost
    assert main(["cache", "--dir", str(tmp_path), "--compile", "--clear"]) == EXIT_BAD_INPUT
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
