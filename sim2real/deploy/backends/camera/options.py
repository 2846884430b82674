"""``deploy-run --camera-source NAME=KIND:WHERE[,loop]``: which hardware camera feeds the policy's
image block named ``NAME`` (its ``camera``), read and checked here (:func:`parse_camera_source`)
before anything opens:

=====================  ==================================================================
value                  the camera
=====================  ==================================================================
``opencv:0``           V4L2 device ``/dev/video0`` through OpenCV (also ``opencv:/dev/video2``)
``opencv:FILE``        a video file (or an ``rtsp://``/``http://`` stream) played as a camera
``realsense:``         the first RealSense device; ``realsense:SERIAL`` one by its serial
``realsense:FILE.bag``  a RealSense recording played back
``ros2:/TOPIC``        ``sensor_msgs/Image`` on a ROS 2 topic; ``/TOPIC/compressed``:
                       ``sensor_msgs/CompressedImage`` (image_transport's naming)
=====================  ==================================================================

``,loop`` after a file or a bag starts it again at its end (else the camera falls silent there,
and the runtime stops the robot as for any stale camera).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from sim2real.deploy.spec.camera import CameraError

KINDS = ("opencv", "realsense", "ros2")
#: The option's expected form, in every refusal.
FORM = (
    "expected NAME=KIND:WHERE[,loop] with KIND:WHERE one of opencv:INDEX, opencv:/dev/videoN, "
    "opencv:FILE, realsense:, realsense:SERIAL, realsense:FILE.bag, ros2:/TOPIC"
)
#: A ROS 2 topic name (``rcl``'s rules, simplified: letters, digits, '_', '/', '~').
TOPIC = re.compile(r"^[~/]?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


@dataclass(frozen=True)
class CameraSource:
    """One ``--camera-source`` value: the block's camera ``name``, the driver ``kind``
    (``opencv``, ``realsense``, ``ros2``), ``where`` (device, file, serial or topic), ``loop``
    (a file or bag again at its end) and the option as given, ``text``."""

    name: str
    kind: str
    where: str
    loop: bool = False
    text: str = ""

    @property
    def label(self) -> str:
        """How a refusal names it: ``--camera-source NAME=KIND:WHERE``."""
        return f"--camera-source {self.text}"


def parse_camera_source(text: str) -> CameraSource:
    """``NAME=KIND:WHERE[,loop]`` (module docstring) as a :class:`CameraSource`.

    Raises:
        CameraError: a value of another form, an unknown kind, an empty device or file, a
            serial that is not digits, a topic that is no ROS 2 name, ``loop`` on a device or
            topic (one line naming ``--camera-source``, the value and the expected form).
    """
    head = f"--camera-source {text!r}"
    name, eq, rest = text.partition("=")
    kind, colon, where = rest.partition(":")
    if not (eq and colon and name.strip()):
        raise CameraError(f"{head}: {FORM}")
    if kind not in KINDS:
        raise CameraError(f"{head}: unknown camera kind '{kind}'; {FORM}")
    loop = where.endswith(",loop")
    where = where[: -len(",loop")] if loop else where
    file = kind == "opencv" and not (where.isdigit() or where.startswith("/dev/"))
    file = file or (kind == "realsense" and where.lower().endswith(".bag"))
    if kind == "opencv" and not where:
        raise CameraError(f"{head}: opencv needs a device index, /dev/videoN or a file; {FORM}")
    if kind == "realsense" and not (where == "" or where.isdigit() or file):
        raise CameraError(
            f"{head}: realsense needs nothing (the first device), a serial number of digits or "
            f"a .bag recording; {FORM}"
        )
    if kind == "ros2" and not TOPIC.match(where):
        raise CameraError(f"{head}: '{where}' is not a ROS 2 topic name; {FORM}")
    if loop and not file:
        raise CameraError(f"{head}: ',loop' plays a file or a .bag again; a device or topic "
                          "cannot loop")  # fmt: skip
    return CameraSource(name.strip(), kind, where, loop, text)
