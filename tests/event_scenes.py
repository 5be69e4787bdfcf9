"""Scenes the contact-event tests build themselves: a fast impact and a
domino row (shared by tests/queries/test_queries_event.py and
tests/batch_sim/test_mjx_events.py)."""

# A ball falling 13 m hits a stiff, bouncy floor at 16 m/s: its contact lasts
# a few milliseconds, less than a stored frame (8.3 ms at 120 fps).
FAST_XML = """
<mujoco>
  <option timestep="0.001"/>
  <worldbody>
    <geom name="floor" type="plane" size="3 3 0.1" solref="-1e6 -10"/>
    <body name="ball" pos="0 0 13.05"><freejoint/><geom type="sphere" size="0.05" mass="0.2" solref="-1e6 -10"/></body>
  </worldbody>
</mujoco>
"""


def domino_row_xml(n: int = 6) -> str:
  """``n`` dominoes 20 cm tall standing 12 cm apart in a row along x."""
  dominoes = "".join(f'<body name="domino_{k}" pos="{0.12 * k:.2f} 0 0.1"><freejoint/>'
                     f'<geom type="box" size="0.01 0.05 0.1" mass="0.05"/></body>' for k in range(n))
  return (f'<mujoco><option timestep="0.002"/><worldbody><geom name="floor" type="plane" size="3 3 0.1"/>'
          f'{dominoes}</worldbody></mujoco>')
