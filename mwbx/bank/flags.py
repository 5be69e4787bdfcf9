"""A world's status flags (``Bank.flags``, u8[W]: several may be set)."""

FLAG_FINISHED = 1  # its run ended (the end time, at rest, or stopped)
FLAG_AT_REST = 2  # came to rest before the end time (stepping stopped there)
FLAG_UNSTABLE = 4  # non-finite or runaway state (stopped there)
FLAG_SIM_ERROR = 8  # MuJoCo raised an error while stepping it (stopped there)
# A step may have needed more contacts than the batched engine's budget
# (mwbx.batch_sim.contact_budget): kept, but out of matches like unstable worlds.
FLAG_CONTACT_OVERFLOW = 16
INVALID = FLAG_UNSTABLE | FLAG_SIM_ERROR | FLAG_CONTACT_OVERFLOW  # left out of every query's matches
