"""uvd — hardware-in-the-loop control daemon for fully actuated underwater vehicles.

The algorithms follow C. J. McFarland, *Adaptive Identification and Control for Underwater
Vehicles*, PhD thesis, Johns Hopkins University, 2013 ("the thesis").
"""

from importlib.metadata import PackageNotFoundError, version

from uvd import _jitcache

_jitcache.configure()  # before numba is imported anywhere: see uvd/_jitcache.py

try:
    __version__ = version("uvd")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
