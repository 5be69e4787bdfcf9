"""MuJoCo joint types as plain ints, and how many qpos / qvel entries each has.

Compare joint types as ints (``int(m.jnt_type[j]) == JNT_HINGE``): on MuJoCo 4
``mjtJoint.mjJNT_HINGE == np.int32(3)`` is False, so ``m.jnt_type[j] in
(mjtJoint.mjJNT_HINGE, …)`` never matches. ``tests/test_config.py`` checks
these values against ``mujoco.mjtJoint``.
"""

JNT_FREE = 0
JNT_BALL = 1
JNT_SLIDE = 2
JNT_HINGE = 3

# Entries of qpos and of qvel per joint, by joint type.
QPOS_WIDTH = {JNT_FREE: 7, JNT_BALL: 4, JNT_SLIDE: 1, JNT_HINGE: 1}
DOF_WIDTH = {JNT_FREE: 6, JNT_BALL: 3, JNT_SLIDE: 1, JNT_HINGE: 1}
