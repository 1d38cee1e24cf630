"""Reaching the Prefect API a run records itself on (issues 45, 46): wait for a server still starting, give up in one
line when none answers, and notice a server lost mid-run.

Prefect-free (``urllib`` only): the CLI checks the API before it imports Prefect's client, whose own failure is a
430-line traceback after ~17 s of retries (``PREFECT_CLIENT_MAX_RETRIES`` with backoff) and, for a server killed
mid-run, a wait of ~10 min (every state, log and event call retried, each up to ``PREFECT_API_REQUEST_TIMEOUT``,
60 s) before its traceback.

A server answers ``GET <api>/health`` with 200 once its database is migrated: uvicorn runs the application's startup
before it binds its port, so a server still starting refuses connections, like a server that is not there. Both are
waited for up to :attr:`ApiSettings.wait_s` with a progress line, then refused in one line
(:class:`ApiUnreachable`, exit 2).
"""

from __future__ import annotations

import os
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from hadal.errors import ConfigError

#: environment variables of :class:`ApiSettings` (the API is the host's, not a dive's: no pipeline.yaml section)
ENV = {"wait_s": "HADAL_API_WAIT_S", "lost_s": "HADAL_API_LOST_S"}


class ApiSettings(BaseModel):
    """How long hadal waits for the Prefect API (seconds), from ``HADAL_API_WAIT_S`` / ``HADAL_API_LOST_S``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    wait_s: float = Field(
        30.0, ge=0, le=600,
        description="before a run: how long to wait for a Prefect API that does not answer yet (a server still "
                    "starting) before a one-line error")
    lost_s: float = Field(
        60.0, ge=2, le=600,
        description="during a run: how long the Prefect API may stop answering before the run is ended, with what "
                    "it published listed")
    probe_timeout_s: float = Field(2.0, gt=0, le=60, description="timeout of one /health request")
    poll_s: float = Field(1.0, gt=0, le=60, description="interval between /health requests")


class ApiUnreachable(ConfigError):
    """The Prefect API did not answer within the wait (a one-line error, exit 2)."""


def api_settings(environ: dict[str, str] | None = None) -> ApiSettings:
    """:class:`ApiSettings` from the environment; a value that is not a number in range is a one-line ConfigError."""
    env = os.environ if environ is None else environ
    given = {k: env[v] for k, v in ENV.items() if env.get(v, "").strip()}
    try:
        return ApiSettings.model_validate(given)
    except ValidationError as exc:
        err = exc.errors()[0]
        name = ENV.get(str(err["loc"][0]), str(err["loc"][0]))
        raise ConfigError(f"{name}={given.get(str(err['loc'][0]))!r}: {err['msg']}") from None


def health_url(api_url: str) -> str:
    return api_url.rstrip("/") + "/health"


def probe(api_url: str, timeout_s: float) -> str | None:
    """``None`` when the API answers ``/health`` with 200 within ``timeout_s``, else why not, in a few words."""
    try:
        with urllib.request.urlopen(health_url(api_url), timeout=timeout_s) as resp:
            return None if resp.status == 200 else f"HTTP {resp.status}"
    except urllib.error.HTTPError as exc:
        return f"HTTP {exc.code}"
    except urllib.error.URLError as exc:
        reason = exc.reason
        if isinstance(reason, ConnectionRefusedError):
            return "connection refused"
        if isinstance(reason, TimeoutError):
            return f"no answer within {timeout_s:g} s"
        return str(getattr(reason, "strerror", None) or reason)
    except TimeoutError:
        return f"no answer within {timeout_s:g} s"
    except (OSError, ValueError) as exc:  # reset, bad URL, ...
        return str(getattr(exc, "strerror", None) or exc) or type(exc).__name__


def wait_for_api(api_url: str, settings: ApiSettings, say: Callable[[str], None]) -> float:
    """Return once the API answers (seconds waited); ``say`` gets one progress line when it does not answer at
    once and one about every 10 s after. :class:`ApiUnreachable` after ``settings.wait_s``."""
    t0 = time.monotonic()
    deadline = t0 + settings.wait_s
    why = probe(api_url, max(0.1, min(settings.probe_timeout_s, settings.wait_s / 2)))  # leaves time to say it
    said = None
    while why is not None:
        now = time.monotonic()
        if now >= deadline:
            break
        if said is None or now - said >= 10.0:
            say(f"waiting for the Prefect API at {api_url} ({why}; a server still starting?), "
                f"up to {deadline - now:.0f} s more ({ENV['wait_s']})")
            said = now
        time.sleep(min(settings.poll_s, deadline - now))
        why = probe(api_url, max(0.1, min(settings.probe_timeout_s, deadline - time.monotonic())))
    if why is None:
        return time.monotonic() - t0
    raise ApiUnreachable(
        f"the Prefect API at {api_url} cannot be reached ({why}; waited {settings.wait_s:g} s, {ENV['wait_s']}): "
        "start it (hadal server start) or unset PREFECT_API_URL to let hadal start a temporary server")


class ApiWatch:
    """A daemon thread that checks the API's ``/health`` every ``poll_s`` during a run and calls ``on_lost(seconds,
    why)`` once when it has not answered for ``lost_s`` (then stops)."""

    def __init__(self, api_url: str, settings: ApiSettings, on_lost: Callable[[float, str], None]):
        self.api_url, self.settings, self.on_lost = api_url, settings, on_lost
        self.last_ok = time.monotonic()
        self.why: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="hadal-api-watch", daemon=True)

    def start(self) -> ApiWatch:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def answering(self) -> bool:
        """Whether the API answers now (one probe)."""
        self.why = probe(self.api_url, self.settings.probe_timeout_s)
        if self.why is None:
            self.last_ok = time.monotonic()
        return self.why is None

    def _loop(self) -> None:
        while not self._stop.wait(self.settings.poll_s):
            if self.answering():
                continue
            silent = time.monotonic() - self.last_ok
            if silent >= self.settings.lost_s and not self._stop.is_set():
                self.on_lost(silent, self.why or "no answer")
                return
