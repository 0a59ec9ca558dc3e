"""The compiled-module cache: per user ($XDG_CACHE_HOME/derive, 0700), refused when
someone else could have written it, and filled atomically (derive/build.py)."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from _backend_kf import steady_reference, steady_unit

from derive import build
from derive.apps.bench.machine import probe
from derive.build import UnsafeCacheError, build_c, cache_dir
from derive.emit.render import render_files
from derive.emit.write import write_files

ROOT = Path(__file__).resolve().parents[2]
needs_root = pytest.mark.skipif(os.getuid() != 0, reason="giving a file to another user "
                                 "needs root")


@pytest.fixture
def c_file(tmp_path):
    unit = steady_unit("sskf")
    paths = write_files(tmp_path / "src", unit.model, render_files(unit))
    return next(p for p in paths if p.suffix == ".c")


@pytest.fixture
def xdg(tmp_path, monkeypatch):
    """A fresh XDG_CACHE_HOME, and no library loaded earlier in this process."""
    home = tmp_path / "xdg"
    monkeypatch.setenv("XDG_CACHE_HOME", str(home))
    monkeypatch.setattr(build, "_LOADED", {})
    return home


def test_the_default_cache_is_private_to_the_user(xdg, c_file):
    module = build_c(c_file)
    cache = xdg / "derive"
    assert cache_dir() == cache
    assert (cache.stat().st_mode & 0o777) == 0o700 and cache.stat().st_uid == os.getuid()
    assert module.path.parent == cache
    zs, x0 = np.ones((5, 1)), np.zeros(2)
    np.testing.assert_allclose(module.run(zs, x0), steady_reference(zs, x0), rtol=1e-13)


def test_a_relative_xdg_cache_home_is_ignored(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "derive"


@pytest.mark.parametrize("mode", [0o777, 0o770, 0o702])
def test_a_cache_others_can_write_is_refused(xdg, c_file, mode):
    (xdg / "derive").mkdir(parents=True)
    (xdg / "derive").chmod(mode)
    with pytest.raises(UnsafeCacheError, match="writable by group or others"):
        build_c(c_file)
    assert list((xdg / "derive").iterdir()) == []


@needs_root
def test_a_cache_of_another_user_is_refused(xdg, c_file):
    (xdg / "derive").mkdir(parents=True, mode=0o700)
    os.chown(xdg / "derive", 4242, -1)
    with pytest.raises(UnsafeCacheError, match="belongs to user id 4242"):
        build_c(c_file)


@needs_root
def test_a_library_planted_by_another_user_is_not_loaded(xdg, c_file, monkeypatch):
    library = next(build_c(c_file).path.glob("*.so"))
    os.chown(library, 4242, -1)
    monkeypatch.setattr(build, "_LOADED", {})
    with pytest.raises(UnsafeCacheError, match="compiled library .* belongs to user id 4242"):
        build_c(c_file)


def test_a_library_others_can_write_is_not_loaded_but_built_again(xdg, c_file, monkeypatch):
    """Under umask 002 (Debian's default with a private group) cffi leaves the library
    group-writable: derive closes it before the entry is renamed into place, and an
    entry of the user's left group-writable (by an older derive, or changed since) is
    never loaded: it is moved aside and built again, under umask 022 as under 002."""
    previous = os.umask(0o002)
    try:
        module = build_c(c_file)
    finally:
        os.umask(previous)
    library = next(module.path.glob("*.so"))
    assert library.stat().st_mode & 0o022 == 0
    library.chmod(0o666)
    planted = library.stat().st_ino
    monkeypatch.setattr(build, "_LOADED", {})
    again = build_c(c_file)
    rebuilt = next(again.path.glob("*.so"))
    assert rebuilt.stat().st_ino != planted and rebuilt.stat().st_mode & 0o022 == 0
    zs, x0 = np.ones((5, 1)), np.zeros(2)
    np.testing.assert_allclose(again.run(zs, x0), steady_reference(zs, x0), rtol=1e-13)


@pytest.mark.parametrize("keep", [0, 4096])
def test_a_truncated_library_is_built_again(xdg, c_file, keep):
    """A cached library cut to 0 bytes (or to its first page: it no longer loads) is
    built again instead of failing the load as an internal error. (Built first in
    another process: this one's dlopen would reuse a library it has loaded.)"""
    subprocess.run([sys.executable, "-c", f"from derive.build import build_c; "
                    f"build_c({str(c_file)!r})"], check=True, timeout=300, cwd=ROOT,
                   env={**os.environ, "PYTHONPATH": str(ROOT), "XDG_CACHE_HOME": str(xdg)})
    library = next((xdg / "derive").glob("*/*.so"))
    os.truncate(library, keep)
    module = build_c(c_file)
    assert next(module.path.glob("*.so")).stat().st_size > keep
    zs, x0 = np.ones((5, 1)), np.zeros(2)
    np.testing.assert_allclose(module.run(zs, x0), steady_reference(zs, x0), rtol=1e-13)


def test_the_command_line_refuses_an_unsafe_cache_in_one_line(tmp_path):
    cache = tmp_path / "xdg" / "derive"
    cache.mkdir(parents=True)
    cache.chmod(0o777)
    proc = subprocess.run([sys.executable, "-m", "derive", "verify", "mpt3d_b", "--filter",
                           "kf", "--steps", "5"], capture_output=True, text=True, cwd=ROOT,
                          timeout=300, env={**os.environ, "PYTHONPATH": str(ROOT),
                                            "XDG_CACHE_HOME": str(tmp_path / "xdg")})
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and str(cache) in lines[0] and "writable by group or others" \
        in lines[0], lines
    assert list(cache.iterdir()) == []


CONCURRENT = textwrap.dedent("""
    import sys
    import numpy as np
    from derive.build import build_c
    module = build_c(sys.argv[1])
    print(module.path, module.run(np.ones((5, 1)), np.zeros(2))[-1][0])
""")


def test_two_processes_building_the_same_source_both_load_a_whole_library(xdg, c_file):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "XDG_CACHE_HOME": str(xdg)}
    procs = [subprocess.Popen([sys.executable, "-c", CONCURRENT, str(c_file)], cwd=ROOT,
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    outputs = []
    for proc in procs:
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
        outputs.append(out)
    assert outputs[0] == outputs[1]
    entries = list((xdg / "derive").iterdir())
    assert len(entries) == 1 and Path(outputs[0].split()[0]) == entries[0]   # no work dirs


def test_the_latency_probe_uses_the_same_cache(xdg):
    probe._module(("-O1",))
    assert [p.name.startswith("probe-") for p in (xdg / "derive").iterdir()] == [True]
