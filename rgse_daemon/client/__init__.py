"""The daemon's Python client for scripted campaigns: :class:`RgseClient` (asyncio) and :class:`SyncClient` (for
notebooks and plain scripts), over the daemon's MQTT commands."""

from rgse_daemon.client.client import PromptHandler, RgseClient, Run
from rgse_daemon.client.sync import SyncClient, SyncRun
from rgse_daemon.client.types import (
    CalibrationResult,
    CampaignPoint,
    DaemonState,
    FixtureFrame,
    Identity,
    MassEstimate,
    MeasurementResult,
    ProgressEvent,
    Prompt,
    PropertiesResult,
    Refused,
    Result,
    ResultRefused,
    RunFailed,
    WaitTimeout,
    load_points,
)
from rgse_daemon.runkind import RunKind

__all__ = [
    "CalibrationResult", "CampaignPoint", "DaemonState", "FixtureFrame", "Identity", "MassEstimate",
    "MeasurementResult", "ProgressEvent", "Prompt", "PromptHandler", "PropertiesResult", "Refused", "Result",
    "ResultRefused", "RgseClient", "Run", "RunFailed", "RunKind", "SyncClient", "SyncRun", "WaitTimeout",
    "load_points",
]
