"""Helpers for mwbx's own tests and benchmarks, not part of the API.

They ship in the package only so that ``scripts/`` and ``tests/`` import them
the same way on any checkout:

* :mod:`mwbx.testing.standin`: a stand-in bank over plain arrays (viewer
  tests and benchmarks without sampling);
* :mod:`mwbx.testing.headless`: headless Chromium through Playwright (pages
  and screenshots for browser tests; needs the ``dev`` extra);
* :mod:`mwbx.testing.codec_data`: small MuJoCo models and recorded paths for
  codec and refinement kernel tests.
"""
