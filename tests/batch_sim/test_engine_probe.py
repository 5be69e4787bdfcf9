"""backend auto's probe (mwbx.batch_sim.engine_probe): with fake engines, the
fastest is chosen but never one slower than native, and the table is printed;
without a GPU, auto is native and nothing is probed."""

import io

import pytest

import mwbx
from mwbx.batch_sim import engine_probe
from mwbx.errors import MwbxError


def _engine(steps: int, seconds: float):
  return lambda: (steps, seconds)


def _failing():
  raise RuntimeError("RESOURCE_EXHAUSTED: out of memory\n while allocating")


def test_the_fastest_engine_is_chosen_and_the_table_printed():
  out = io.StringIO()
  result = engine_probe.probe_engines(
      {"native": _engine(1000, 1.0), "mjx:warp": _engine(9000, 2.0), "mjx:jax": _engine(3000, 1.0)},
      out=out, header="probe:")
  assert result.choice == "mjx:warp"
  assert [r.engine for r in result.rows] == ["native", "mjx:warp", "mjx:jax"]
  lines = out.getvalue().splitlines()
  assert lines[0] == "probe:" and "world-steps/s" in lines[1] and "vs native" in lines[1]
  assert lines[2].split() == ["native", "1,000", "1.00x"]
  assert lines[3].split() == ["mjx:warp", "4,500", "4.50x"]
  assert lines[4].split() == ["mjx:jax", "3,000", "3.00x"]
  assert lines[5].strip() == "chosen: mjx:warp"


def test_an_engine_slower_than_native_or_failing_is_never_chosen():
  out = io.StringIO()
  result = engine_probe.probe_engines(
      {"native": _engine(1000, 1.0), "mjx:warp": _failing, "mjx:jax": _engine(999, 1.0)}, out=out)
  assert result.choice == "native"
  assert result.rows[1].error.startswith("RuntimeError: RESOURCE_EXHAUSTED: out of memory while allocating")
  assert f"{'mjx:warp':<16}  failed: RuntimeError" in out.getvalue()
  # A tie keeps native (no compile, no device memory).
  tie = engine_probe.probe_engines({"mjx:jax": _engine(2000, 2.0), "native": _engine(1000, 1.0)}, out=out)
  assert tie.choice == "native"


def test_without_native_the_fastest_that_ran_and_none_is_an_error():
  out = io.StringIO()
  result = engine_probe.probe_engines(
      {"native": _failing, "mjx:warp": _engine(100, 1.0), "mjx:jax": _engine(300, 1.0)}, out=out)
  assert result.choice == "mjx:jax"
  with pytest.raises(MwbxError, match=r"^backend auto: no engine ran in the probe: native: RuntimeError"):
    engine_probe.probe_engines({"native": _failing, "mjx:jax": _engine(0, 1.0)}, out=out)


def test_cpu_only_auto_is_native_without_probing(monkeypatch, tiny_config):
  def no_probe(*args, **kwargs):
    raise AssertionError("probed without a GPU")
  monkeypatch.setattr(engine_probe, "gpu_visible", lambda: False)
  monkeypatch.setattr(engine_probe, "probe_scene", no_probe)
  with mwbx.Sampler(tiny_config, backend="auto") as sampler:
    assert sampler.backend_name == "native" and sampler.probe is None and sampler.contact_budget is None


@pytest.mark.parametrize("fastest", ["native", "mjx:jax"])
def test_with_a_gpu_auto_samples_on_the_probes_choice(monkeypatch, capsys, tiny_config, fastest):
  """The wiring, with a GPU pretended and the engine runs faked: the pilot
  sizes the budget first, then the probe's choice is the sampler's engine."""
  rates = {"native": 1000, "mjx:warp": 500, "mjx:jax": 800}
  rates[fastest] = 2000
  timed = []

  def fake_run(sampler_cls, scene, backend, impl, budget, warp_solver, sleep=None):
    name = backend if impl is None else f"{backend}:{impl}"
    assert budget is not None and budget.source.startswith("pilot")  # the pilot ran before the probe
    def run():
      timed.append(name)
      return rates[name], 1.0
    return run

  monkeypatch.setattr(engine_probe, "gpu_visible", lambda: True)
  monkeypatch.setattr(engine_probe, "_engine_run", fake_run)
  with mwbx.Sampler(tiny_config, backend="auto") as sampler:
    assert sampler.probe.choice == fastest
    assert timed[0] == "native" and set(timed) >= {"native", "mjx:jax"}
    assert sampler.backend_label == fastest
    assert (sampler.contact_budget is not None) == (fastest != "native")
  err = capsys.readouterr().err
  assert "backend auto: a GPU is visible" in err and f"chosen: {fastest}" in err


def test_a_real_engine_run_times_whole_chunks_of_the_scenes_start(tiny_config):
  """Native's probe run (the MJX ones are the same code on another backend):
  PROBE_CHUNKS chunks of the config's chunk size, each world at most
  PROBE_SECONDS long."""
  scene = mwbx.Scene(tiny_config)
  run = engine_probe._engine_run(mwbx.Sampler, scene, "native", None, None, None)  # pylint: disable=protected-access
  steps, seconds = run()
  worlds = engine_probe.PROBE_CHUNKS * tiny_config.sim.chunk_size
  frame = 1 / tiny_config.sim.record_fps  # a world records frames 0..end_frame: one frame past the end time
  most = worlds * round((engine_probe.PROBE_SECONDS + frame) / scene.model.opt.timestep)
  assert 0 < steps <= most and seconds > 0


def test_where_native_sleeps_the_probe_times_mjx_warp_with_sleep(monkeypatch, tiny_config):
  """With sleep on for the native engine, the probe also times mjx:warp with
  island sleep; chosen, the sampler steps MuJoCo Warp with sleep under Newton,
  its awake dofs (nvmax) sized by the native pilot, and records it."""
  pytest.importorskip("warp")
  config = tiny_config.model_copy(update={"sim": tiny_config.sim.model_copy(update={"sleep": True})})
  rates = {"native": 1000, "mjx:warp": 500, "mjx:jax": 800, engine_probe.WARP_SLEEP: 2000}
  asked = {}

  def fake_run(sampler_cls, scene, backend, impl, budget, warp_solver, sleep=None):
    name = backend if impl is None else f"{backend}:{impl}" + ("+sleep" if sleep else "")
    asked[name] = sleep
    return lambda: (rates[name], 1.0)

  monkeypatch.setattr(engine_probe, "gpu_visible", lambda: True)
  monkeypatch.setattr(engine_probe, "_engine_run", fake_run)
  with mwbx.Sampler(config, backend="auto") as sampler:
    assert asked[engine_probe.WARP_SLEEP] is True and asked["mjx:warp"] is None
    assert sampler.probe.choice == engine_probe.WARP_SLEEP and sampler.backend_label == "mjx:warp"
    assert sampler.sleep.enabled and "engine probe" in sampler.sleep.reason
    assert sampler.backend.sleeps and sampler.warp_solver.solver == "newton"
    assert 0 < sampler.contact_budget.nvmax <= sampler.backend.model.nv
    assert sampler.run_record()["sleep"]["enabled"] is True
