"""Shared fixtures: tiny scenes and samplers compiled once per test session."""

import pathlib

import jax
import pytest

import mwbx

TESTS = pathlib.Path(__file__).parent
REPO = TESTS.parent


@pytest.fixture(scope="session")
def tiny_config():
  return mwbx.load_config(TESTS / "scenes" / "tiny.yaml")


@pytest.fixture(scope="session")
def quickstart_config():
  return mwbx.load_config(REPO / "configs" / "quickstart.yaml")


@pytest.fixture(scope="session")
def tiny_native(tiny_config):
  with mwbx.Sampler(tiny_config, backend="native") as sampler:
    yield sampler


@pytest.fixture(scope="session")
def tiny_native_bank(tiny_native):
  bank, _ = tiny_native.run(32, jax.random.key(0))
  return bank
