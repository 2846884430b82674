"""The robot's motion switcher service: is a high-level motion mode (sport mode) still active?

Unitree robots run a high-level controller (the Go2's sport mode, the G1's locomotion) that
commands the motors itself; a low-level program must release it first, or both command the
motors at once. The ``motion_switcher`` service reports the active mode (unitree_sdk2's
``MotionSwitcherClient``: API 1001 ``CheckMode`` returns JSON ``{"name": ..., "form": ...}``,
``name`` empty once released; API 1003 ``ReleaseMode`` releases it) over
:mod:`sim2real.deploy.backends.unitree.unitree_api` requests on ``rt/api/motion_switcher/request`` and
responses on ``rt/api/motion_switcher/response``.
"""

from __future__ import annotations

import json
import time

from sim2real.deploy.backends.unitree.dds import DdsLink
from sim2real.deploy.backends.unitree.unitree_api import Request_, Response_

SERVICE = "motion_switcher"
REQUEST_TOPIC = f"rt/api/{SERVICE}/request"
RESPONSE_TOPIC = f"rt/api/{SERVICE}/response"
#: API ids (unitree_sdk2 motion_switcher_api: CheckMode 1001, SelectMode 1002, ReleaseMode 1003).
CHECK_MODE, SELECT_MODE, RELEASE_MODE = 1001, 1002, 1003

#: How to release the high-level mode, for the error message.
RELEASE_HINT = (
    "release it first: lay the robot down and switch the high-level mode off (Unitree app; or "
    "unitree_sdk2's MotionSwitcherClient.ReleaseMode(), example/motionSwitcher), then run again"
)


def check_mode(link: DdsLink, timeout: float = 2.0) -> dict | None:
    """Ask the robot's motion switcher for its active mode (``CheckMode``).

    Returns:
        The response's JSON (``{"name": "normal", ...}``; ``name`` empty: released), or None
        when no motion switcher answered within ``timeout`` s (a robot or a firmware without
        the service, or an emulator started without it).
    """
    writer = link.generic_writer(REQUEST_TOPIC, Request_)
    reader = link.generic_reader(RESPONSE_TOPIC, Response_)
    end = time.monotonic() + timeout
    while not writer.get_matched_subscriptions() or not reader.get_matched_publications():
        if time.monotonic() > end:  # nobody serves the request topic
            return None
        time.sleep(0.02)
    request = Request_()
    request.header.identity.id = time.monotonic_ns()
    request.header.identity.api_id = CHECK_MODE
    request.parameter = "{}"
    writer.write(request)
    while time.monotonic() < end:
        for response in reader.take(16):
            identity = getattr(getattr(response, "header", None), "identity", None)
            if identity is None or identity.id != request.header.identity.id:
                continue
            if response.header.status.code != 0:
                return None
            try:
                return json.loads(response.data)
            except ValueError:
                return None
        time.sleep(0.01)
    return None
