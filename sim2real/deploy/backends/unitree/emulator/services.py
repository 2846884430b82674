"""The emulated robot's motion switcher service (:mod:`sim2real.deploy.backends.unitree.motion_switcher`).

Answers ``CheckMode`` with the emulated high-level mode (``{"name": mode, "form": "0"}``; empty
once released) and ``ReleaseMode`` by releasing it; other calls with status code 1. While a mode
is active the emulated robot ignores LowCmd, as its own controller has the motors.
"""

from __future__ import annotations

import json

from sim2real.deploy.backends.unitree.dds import DdsLink
from sim2real.deploy.backends.unitree.motion_switcher import (
    CHECK_MODE,
    RELEASE_MODE,
    REQUEST_TOPIC,
    RESPONSE_TOPIC,
)
from sim2real.deploy.backends.unitree.unitree_api import Request_, Response_


class MotionSwitcherService:
    """The service on ``link`` with the high-level mode ``mode`` ('' : none active).

    Attributes:
        mode: The active high-level mode's name ('' : released). calls: requests answered.
    """

    def __init__(self, link: DdsLink, mode: str = ""):
        self.mode, self.calls = mode, 0
        self._requests = link.generic_reader(REQUEST_TOPIC, Request_)
        self._responses = link.generic_writer(RESPONSE_TOPIC, Response_)

    def poll(self) -> None:
        """Answer the requests received since the last poll."""
        for request in self._requests.take(16):
            identity = getattr(getattr(request, "header", None), "identity", None)
            if identity is None:
                continue
            response = Response_()
            response.header.identity.id = identity.id
            response.header.identity.api_id = identity.api_id
            if identity.api_id == CHECK_MODE:
                response.data = json.dumps({"name": self.mode, "form": "0"})
            elif identity.api_id == RELEASE_MODE:
                self.mode = ""
                response.data = "{}"
            else:
                response.header.status.code = 1
            self._responses.write(response)
            self.calls += 1
