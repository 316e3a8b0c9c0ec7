"""A fleet of devices: batch calibration on dask.distributed (:mod:`~imucal.fleet.batch`), one
summary row per session (:mod:`~imucal.fleet.summary`), pass/fail against a spec
(:mod:`~imucal.fleet.spec`) and a calibration store per device (:mod:`~imucal.fleet.store`).

Pure Python above the core: it never imports rerun; the command line calls it.
"""
