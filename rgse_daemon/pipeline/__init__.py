"""The numbers of the paper's method, one step a module.

* The mass: pre-processing (:mod:`.preprocess`), loop integrity (:mod:`.integrity`), the calibration models K
  (:mod:`.calibration`) and their selection (:mod:`.selection`), thermal drift (:mod:`.thermal`), the mass equations
  (:mod:`.mass`), the in-line mass (:mod:`.inline`), its uncertainty (:mod:`.uncertainty`), the operating-point check
  (:mod:`.envelope`), the loops' stop rule (:mod:`.stopping`), the parameter study (:mod:`.study`) and the campaign
  planner (:mod:`.planning`).
* The CoG: the estimator and its poses (:mod:`.cog`), the per-axis gain models (:mod:`.axis_gain`) and the torsional
  campaign that fits them (:mod:`.torsion`).
* The inertia: the identification (:mod:`.inertia`) and its excitation moves (:mod:`.excitation`).

Pure numpy/scipy: no I/O, no asyncio. Loading trace files and manifests lives in :mod:`rgse_daemon.manifest`.
"""
