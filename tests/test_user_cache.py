"""The models' caches follow the XDG base directory specification (models/cache.py):
$XDG_CACHE_HOME/artifem/<name>, ~/.cache when the variable is unset, empty or relative."""

import pathlib

import artifem  # noqa: F401  (must precede dolfinx / petsc4py)
from artifem.models.cache import user_cache


def test_the_cache_is_under_xdg_cache_home_or_dot_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert user_cache("foot") == tmp_path / "xdg" / "artifem" / "foot"
    for unset in ("", "relative/cache"):
        monkeypatch.setenv("XDG_CACHE_HOME", unset)
        assert user_cache("foot") == tmp_path / "home" / ".cache" / "artifem" / "foot"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert user_cache("foot-reduced") == pathlib.Path.home() / ".cache" / "artifem" / "foot-reduced"
