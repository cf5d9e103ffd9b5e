"""seekopt: seek-profile optimisation for HDD servo engineers.

Pipeline: ``logs -> identification -> plant -> design -> simulation -> export``.
The ``identification`` package turns seek logs into a :class:`~identification.model.plant.ModalPlant`;
this package designs, simulates, sweeps and exports seek profiles for it.
"""
__version__ = "0.1.0"
