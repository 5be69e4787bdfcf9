"""The chosen world delivered: USD (time-sampled poses), mp4 (offscreen
MuJoCo rendering) and npz (decoded qpos and body poses).

usd-core and imageio-ffmpeg (the ``export`` extra) are imported on first use.
"""

from mwbx.export.npz import export_npz
from mwbx.export.poses import WorldPoses
from mwbx.export.poses import world_poses
from mwbx.export.usd import export_usd
from mwbx.export.video import render_video
