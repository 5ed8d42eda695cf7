"""The CPU fusion-emitter workaround (mara_mjx/_xla.py)."""

from __future__ import annotations

import os

import pytest

from mara_mjx import _xla


def test_flag_is_in_effect_for_this_session():
    # mara_mjx was imported before JAX started (conftest), with a jaxlib in range
    assert _xla.FLAG in os.environ.get("XLA_FLAGS", "")


def test_user_setting_wins_and_unknown_versions_are_left_alone(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert not _xla.apply_cpu_fusion_workaround()
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_use_fusion_emitters=true"

    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    monkeypatch.setattr(_xla, "JAXLIB_VERSIONS", ((0, 1), (0, 2)))
    assert not _xla.apply_cpu_fusion_workaround()
    monkeypatch.setattr(_xla, "JAXLIB_VERSIONS", ((0, 1), (99, 0)))
    assert _xla.apply_cpu_fusion_workaround()
    assert os.environ["XLA_FLAGS"] == f"--xla_force_host_platform_device_count=2 {_xla.FLAG}"


@pytest.mark.parametrize("text, expected", [("0.10.2", (0, 10)), ("0.11.0rc1", (0, 11))])
def test_version_parsing(text, expected):
    assert _xla._version(text) == expected
