"""File formats: parameter files, vehicle files, run logs, figures.

The pure packages (:mod:`uvd.model`, :mod:`uvd.control`, :mod:`uvd.estimation`) read and write
no files; everything that touches a file for them lives here, above them and below the core
(layer order in ``docs/architecture.md``).
"""
