"""The one error hierarchy of uvd.

Every error subclasses :class:`UvdError` *and* the matching built-in, so callers can catch
either (``except TimeoutError`` still works). Vendor exceptions are re-raised ``from`` their
cause.
"""


class UvdError(Exception):
    """Base class of every error uvd raises on purpose."""


class ConfigError(UvdError, ValueError):
    """A configuration file or value is invalid; the message names the file, key and reason."""


class ParameterError(UvdError, ValueError):
    """A parameter set is physically invalid (M not SPD, drag not dissipative, wrong shape)."""


class FrameError(UvdError, ValueError):
    """A wire frame could not be decoded (bad sync, length, checksum or field)."""


class ChecksumError(FrameError):
    """A frame's checksum does not match its contents."""


class SensorTimeout(UvdError, TimeoutError):
    """A sensor produced no valid frame within its allowed age."""


class TransportError(UvdError, OSError):
    """A serial port, socket or CAN bus failed."""


class BusError(TransportError):
    """The CAN bus is error-passive, bus-off, or a send failed."""


class ExperimentError(UvdError, RuntimeError):
    """An experiment could not be run as asked (unknown name, bad option)."""


class LogReadError(ConfigError):
    """Another system's recording cannot be read as asked: unreadable, truncated or corrupted
    file, a topic or field the log profile names that is missing, a wrong unit. The message
    names the file and the topic."""
