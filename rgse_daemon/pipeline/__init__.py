"""The mass pipeline: pre-processing, calibration models, mass equations, uncertainty and parameter study.

Pure numpy/scipy: no I/O, no asyncio. Loading trace files and manifests lives in :mod:`rgse_daemon.manifest`.
"""
