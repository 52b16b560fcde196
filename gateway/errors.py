"""The gateway's own error types; transport and library errors are converted into these."""

from __future__ import annotations


class GatewayError(Exception):
    """Base of every error the gateway raises on purpose."""


class ConfigError(GatewayError):
    """A configuration file or value is invalid (the message names file, key and range)."""


class DeviceError(GatewayError):
    """A device could not be read or answered with an error."""


class DeviceTimeoutError(DeviceError, TimeoutError):
    """A device did not answer in time."""


class DeviceConnectionError(DeviceError, ConnectionError):
    """The connection to a device could not be made or was lost."""


class DeviceExceptionResponse(DeviceError):
    """The device answered with a Modbus exception response."""

    def __init__(self, message: str, exception_code: int) -> None:
        super().__init__(message)
        self.exception_code = exception_code


class DecodeError(DeviceError):
    """A response could not be decoded (wrong length, garbled frame)."""


class ShortAnswerError(DecodeError):
    """A well-formed answer with fewer registers than the request asked for (some devices
    answer a read that runs past the end of their map with the registers they have)."""

    def __init__(self, message: str, asked: int, got: int) -> None:
        super().__init__(message)
        self.asked = asked
        self.got = got


class DeviceMismatchError(DeviceError):
    """The device answers, but is not the device the configuration describes (a product
    id, channel count or identification differs from what the configuration expects)."""


class WriteNotAllowedError(GatewayError):
    """A write to a device that the configuration does not allow writes to."""


class RecordError(GatewayError):
    """A measurement record is malformed (the message names file, line and column)."""
