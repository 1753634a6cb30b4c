"""Errors a user reads. Every message names the file or setting at fault and what to do."""


class VortxError(Exception):
    """Base class for user-facing failures of the engine (shown as-is in the CLI and in Blender)."""


class CaptureError(VortxError):
    """A capture folder or file cannot be used as input."""


class PoseError(VortxError):
    """Camera poses could not be estimated or are invalid."""


class WeightsError(VortxError):
    """A weights file is missing, unreadable or does not match the model."""


class NativeStepError(VortxError):
    """A native library step (xatlas, fast-simplification) crashed, hung past its time limit, or could
    not be started in its child process (engine/native_worker.py)."""


class Cancelled(VortxError):
    """The user cancelled a long-running job."""

    def __init__(self, message: str = "cancelled by the user") -> None:
        super().__init__(message)
