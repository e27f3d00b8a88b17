"""Exception tree of tvsd.

Each error also subclasses the built-in type a caller would naturally catch (as python-can's
``can/exceptions.py`` does), and every user-facing error carries an exit status, so the command
line turns it into one clear line and a documented exit code instead of a traceback.
"""

from __future__ import annotations

# Exit statuses of tvsd and tvsctl (documented in README.md, "Exit statuses").
EXIT_OK = 0
EXIT_FAILURE = 1  # the command ran but the result is a failure (e.g. a check did not pass)
EXIT_USAGE = 2  # bad input: arguments, config, files, requests
EXIT_UNAVAILABLE = 3  # a device or the daemon is not reachable
EXIT_INTERNAL = 70  # a bug in tvsd (EX_SOFTWARE)
EXIT_PIPE = 141  # stdout's reader went away (`tvsctl … | head`): 128 + SIGPIPE, as a C tool's shell status


class TvsdError(Exception):
    """Base of every error tvsd raises on purpose."""

    exit_status = EXIT_FAILURE


class UsageError(TvsdError, ValueError):
    """A user mistake: bad argument, bad value. The message says what was seen and the fix."""

    exit_status = EXIT_USAGE


class ConfigError(UsageError):
    """A configuration file is unreadable or invalid (file, line, key, expected)."""


class DataFileError(UsageError):
    """A data file (recording, calibration) is unreadable or breaks its contract."""


class DeviceError(TvsdError, OSError):
    """A device (I2C sensor, MCU link, CAN bus) failed or is not there."""

    exit_status = EXIT_UNAVAILABLE


class ProtocolError(DeviceError):
    """Bytes on a wire broke the protocol (bad frame, wrong version, table mismatch)."""


class DaemonUnavailable(TvsdError, ConnectionError):
    """tvsctl could not reach tvsd."""

    exit_status = EXIT_UNAVAILABLE
