"""Cameras on hardware: a driver's frames converted to what a policy's image block reads (depth in
metres from 16-bit units and a depth scale, colour in the block's channel order), refused in one
line when they cannot be; a recorded video written here by cv2.VideoWriter and played back by
OpenCV as a camera, its frames' ages the file's timestamps; ROS 2 Image and CompressedImage frames
published by a second node, their ages from the header stamps written; deploy-run's
--camera-source refusals. Real decoders, no mocks; ages are judged against the stamps written,
never against the wall clock."""

from __future__ import annotations

import importlib.util
import time
from types import SimpleNamespace as NS

import numpy as np
import pytest

from sim2real.deploy.backends.camera.convert import FrameTarget, target_for, to_target
from sim2real.deploy.backends.camera.feed import CameraFeed
from sim2real.deploy.backends.camera.options import parse_camera_source
from sim2real.deploy.backends.camera.realsense_source import depth_metres
from sim2real.deploy.spec.camera import CameraError, RgbImageBlock
from tests.test_camera import TINY, depth_policy
from tests.test_ros2 import ros_domain  # noqa: F401 - the fixture

DEPTH = FrameTarget((12, 16), "depth", "head_depth")
#: What deploy-run says of an opencv: source where OpenCV is not installed (None: it is).
OPENCV_MISSING = (
    None
    if importlib.util.find_spec("cv2")
    else "OpenCV does not import; install the extra 'camera'"
)
RGB = FrameTarget((12, 16), "rgb", "front")


def one_line(err) -> str:
    line = str(err.value)
    assert "\n" not in line
    return line


# ---------------------------------------------------------------------- conversion, no driver
def test_depth_units_become_metres_and_invalid_pixels_stay_zero():
    mm = np.full((12, 16), 1500, np.uint16)
    mm[0, 0] = 0  # no stereo match
    d = to_target(mm, "16UC1", DEPTH, "t")
    assert d.dtype == np.float32 and d[0, 0] == 0 and d[1, 1] == pytest.approx(1.5)
    metres = np.full((12, 16), 2.25, np.float32)
    metres[0, :3] = [np.nan, np.inf, -1.0]  # unknown in a 32FC1 image
    d = to_target(metres, "32FC1", DEPTH, "t")
    assert (d[0, :3] == 0).all() and d[5, 5] == pytest.approx(2.25)
    # a RealSense D405's depth unit is 0.1 mm: the device's scale, not ROS's millimetre
    units = np.full((12, 16), 12345, np.uint16)
    np.testing.assert_allclose(to_target(units, "16UC1", DEPTH, "t", 1e-4), 1.2345, rtol=1e-6)
    np.testing.assert_allclose(depth_metres(units, 1e-4), 1.2345, rtol=1e-6)


def test_colour_is_put_in_the_blocks_channel_order():
    bgr = np.zeros((12, 16, 3), np.uint8)
    bgr[..., 0] = 200  # blue
    rgb = to_target(bgr, "bgr8", RGB, "t")
    assert rgb[0, 0].tolist() == [0, 0, 200]
    assert to_target(rgb, "rgb8", RGB, "t")[0, 0].tolist() == [0, 0, 200]
    as_bgr = to_target(rgb, "rgb8", FrameTarget((12, 16), "bgr", "front"), "t")
    assert as_bgr[0, 0].tolist() == [200, 0, 0]
    assert target_for(TINY) == FrameTarget((12, 16), "depth", "head_depth")
    # a colour block's frames reach the runtime in R, G, B order, whatever order its graph reads
    # (the camera stage's preprocessing flips them), under the frame's colour fields
    wrist = RgbImageBlock(camera="wrist", shape=(4, 5), channel_order="BGR")
    assert target_for(wrist) == FrameTarget((4, 5), "rgb", "wrist")
    feed = CameraFeed(target_for(wrist), "t", monotonic=lambda: 1.0)
    feed.put(np.full((4, 5, 3), 7, np.uint8), "rgb8", captured=0.9)
    frame = NS(time=np.array([2.0]))
    feed.fill(frame)
    assert frame.rgb_image.shape == (1, 4, 5, 3) and frame.rgb_stamp[0] == pytest.approx(1.9)
    assert not hasattr(frame, "depth_image")


@pytest.mark.parametrize(
    ("image", "encoding", "target", "words"),
    [
        (
            np.zeros((10, 16), np.uint16),
            "16UC1",
            DEPTH,
            "10 x 16 pixels; the policy's image block expects 12 x 16",
        ),
        (np.full((12, 16), "1.0"), "32FC1", DEPTH, "a frame of dtype <U3; expected numbers"),
        (np.zeros((12, 16, 3), np.uint8), "bgr8", DEPTH, "a 'bgr8' picture for a depth block"),
        (np.zeros((12, 16), np.uint16), "16UC1", RGB, "'16UC1' depth for a rgb block"),
        (np.zeros((12, 16), np.uint8), "mono8", RGB, "a grey (mono8) frame for a rgb block"),
        (np.zeros((12, 16, 4), np.uint8), "rgba8", RGB, "encoding 'rgba8' is not read"),
        (np.zeros((12, 16), np.uint8), "rgb8", RGB, "shape (12, 16) for encoding 'rgb8'"),
    ],
)
def test_a_frame_the_block_cannot_read_is_refused_in_one_line(image, encoding, target, words):
    with pytest.raises(CameraError) as err:
        to_target(image, encoding, target, "--camera-source x=ros2:/cam")
    line = one_line(err)
    assert line.startswith(f"--camera-source x=ros2:/cam: camera '{target.camera}'"), line
    assert words in line


def test_a_v4l2_stamp_is_read_on_the_monotonic_clock_and_another_clock_is_mapped():
    from sim2real.deploy.backends.camera.feed import ClockMap
    from sim2real.deploy.backends.camera.opencv_source import device_capture_time

    clock = ClockMap()
    # a buffer stamped 40 ms before it was dequeued, on CLOCK_MONOTONIC: its age counts the 40 ms
    assert device_capture_time(1000.00, 1000.04, clock) == (1000.00, "monotonic")
    # a camera stamping on its own clock (1e6 s off): the least delayed frame sets the offset
    assert device_capture_time(5.00, 1000.05, clock) == (pytest.approx(1000.05), "mapped")
    assert device_capture_time(5.10, 1000.13, clock) == (pytest.approx(1000.13), "mapped")
    # the second came 20 ms sooner after its stamp than the first: the offset is now 995.03 s
    late, _ = device_capture_time(5.20, 1000.40, clock)  # this one came 0.17 s after its stamp
    assert late == pytest.approx(1000.23)  # its age at arrival: 0.17 s


def test_a_frame_refused_mid_run_is_not_delivered_and_the_camera_goes_stale():
    """Before the first good frame a refusal is deploy-run's error; after it, a driver that
    turns to another resolution delivers nothing (the runtime's stage then stops the robot as
    for a silent camera), counted in the report, never raised into the control loop."""
    from sim2real.deploy.backends.camera.feed import CameraFeed

    feed = CameraFeed(DEPTH, "src", monotonic=lambda: 5.0)
    feed.put(np.full((12, 16), 700, np.uint16), "16UC1", 4.9)
    frame = NS(time=np.array([100.0]))
    feed.fill(frame)
    assert frame.depth_stamp[0] == pytest.approx(99.9) and frame.depth_image[
        0, 0, 0
    ] == pytest.approx(0.7, rel=1e-6)
    feed.put(np.zeros((480, 640), np.uint16), "16UC1", 4.95)  # another resolution
    feed.fill(frame)
    assert np.isnan(frame.depth_stamp[0]) and frame.depth_image[0, 0, 0] == pytest.approx(
        0.7, rel=1e-6
    )
    assert feed.summary()["refused"] == 1 and "480 x 640 pixels" in feed.summary()["refusal"]
    early = CameraFeed(DEPTH, "src")
    early.put(np.zeros((480, 640), np.uint16), "16UC1", 1.0)
    with pytest.raises(CameraError, match=r"^src: camera 'head_depth': a frame of 480 x 640"):
        early.wait_first(1.0)


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("head_depth", "expected NAME=KIND:WHERE"),
        ("head_depth=usb:0", "unknown camera kind 'usb'"),
        ("head_depth=opencv:", "opencv needs a device index"),
        ("head_depth=realsense:cam-1", "a serial number of digits or a .bag"),
        ("head_depth=ros2:camera image", "'camera image' is not a ROS 2 topic name"),
        ("head_depth=opencv:0,loop", "a device or topic cannot loop"),
    ],
)
def test_bad_camera_sources_are_refused_in_one_line_naming_the_option(value, words):
    with pytest.raises(CameraError) as err:
        parse_camera_source(value)
    line = one_line(err)
    assert line.startswith(f"--camera-source '{value}'") and words in line


def test_good_camera_sources_are_read():
    s = parse_camera_source("head_depth=opencv:clip.mkv,loop")
    assert (s.name, s.kind, s.where, s.loop) == ("head_depth", "opencv", "clip.mkv", True)
    assert parse_camera_source("d=realsense:").where == ""
    assert parse_camera_source("d=realsense:f.bag,loop").loop
    assert parse_camera_source("d=ros2:/cam/image_raw/compressed").where.endswith("compressed")


# ---------------------------------------------------------------------- OpenCV on recorded video
@pytest.fixture
def cv2():
    return pytest.importorskip(
        "cv2", reason="OpenCV is not installed (the extra 'camera': opencv-python-headless)"
    )


def write_video(cv2, path, frames, fps, depth16=False):
    """``frames`` into ``path`` by cv2.VideoWriter, lossless (FFV1): 16-bit grey for depth."""
    rows, cols = frames[0].shape[:2]
    params = [cv2.VIDEOWRITER_PROP_DEPTH, cv2.CV_16U, cv2.VIDEOWRITER_PROP_IS_COLOR, 0]
    w = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"FFV1"), fps,
                        (cols, rows), params if depth16 else [])  # fmt: skip
    assert w.isOpened()
    for f in frames:
        w.write(f)
    w.release()


def take(source, frame) -> None:
    """One tick's ``source.fill(frame)`` at ``frame.time`` = now on the monotonic clock, the feed
    reading the same instant (its clock is passed in, as its constructor allows): a frame's
    stamp is then its capture time exactly, whatever the machine's load between two reads."""
    now = time.monotonic()
    frame.time[0] = now
    source.feed.monotonic = lambda: now
    source.fill(frame)


def drain(camera) -> list[tuple[np.ndarray, float]]:
    """Every frame the runtime would take from ``camera`` until its file ended: (image, stamp on
    the frame's clock, here the monotonic one)."""
    frame, got = NS(time=np.zeros(1)), []
    end = time.monotonic() + 60.0  # a hung decoder, not a slow machine
    while time.monotonic() < end:
        ended = camera.ended
        take(camera, frame)
        if not np.isnan(frame.depth_stamp[0]):
            got.append((frame.depth_image[0].copy(), float(frame.depth_stamp[0])))
        elif ended:
            return got
        time.sleep(0.005)
    raise AssertionError("the video did not end")


def test_a_recorded_depth_video_plays_as_a_camera_with_the_files_timestamps(cv2, tmp_path):
    from sim2real.deploy.backends.camera.opencv_source import OpenCvCamera

    fps, n = 20.0, 12
    mm = [np.full((12, 16), 1000 + 50 * k, np.uint16) for k in range(n)]
    mm[3][2, 2] = 0  # a hole
    write_video(cv2, tmp_path / "depth.mkv", mm, fps, depth16=True)
    camera = OpenCvCamera(str(tmp_path / "depth.mkv"), DEPTH, "--camera-source d=opencv:F")
    try:
        assert camera.feed.wait_first(30.0).dtype == np.float32
        got = drain(camera)
    finally:
        camera.close()
    assert len(got) >= 2 and camera.stamp_clock == "file"
    index = [round((img[0, 0] - 1.0) / 0.05) for img, _ in got]
    for (img, stamp), k in zip(got, index, strict=True):
        np.testing.assert_allclose(img, mm[k] / 1000.0, rtol=1e-6)  # metres, the hole still 0
        # its age was measured from the file's presentation time (50 ms apart: exact in
        # Matroska's 1 ms time base)
        assert stamp - got[0][1] == pytest.approx((k - index[0]) / fps, abs=1e-6)
    assert index == sorted(set(index))  # newest first, never an old frame after a new one


def test_a_recording_that_ends_feeds_the_runtime_then_goes_stale(cv2, tmp_path):
    """The runtime's camera stage reads the hardware source as it reads the plant's camera; a
    camera that falls silent (here a file at its end; a device unplugged alike) is stale."""
    from sim2real.deploy.backends.camera.opencv_source import OpenCvCamera
    from sim2real.deploy.runtime.camera import CameraInput

    mm = [np.full((12, 16), 900 + 100 * k, np.uint16) for k in range(4)]
    write_video(cv2, tmp_path / "short.mkv", mm, 25.0, depth16=True)
    camera = OpenCvCamera(str(tmp_path / "short.mkv"), DEPTH, "src")
    stage = CameraInput(TINY, 1, stale_limit=0.2, source=camera)
    frame = NS(time=np.zeros(1))
    end = time.monotonic() + 60.0
    try:
        camera.feed.wait_first(30.0)
        while time.monotonic() < end:
            frame.time[0] = time.monotonic()
            stale = stage.update(frame)[0]
            if camera.ended and stale:
                break
            time.sleep(0.01)
    finally:
        camera.close()
    assert camera.ended and stage.stale[0] and stage.taken[0] >= 1
    assert stage.repeated[0] == 0  # a new frame each time, never one again with a new stamp
    assert stage.time_since_fresh[0] > 0.2
    assert stage.stale_phrase(0) == "no fresh frame arrived (dropped or late)"


def test_a_colour_video_reaches_an_rgb_block_in_its_order_and_a_depth_block_refuses_it(
    cv2, tmp_path
):
    from sim2real.deploy.backends.camera.opencv_source import OpenCvCamera

    bgr = [np.zeros((12, 16, 3), np.uint8) for _ in range(3)]
    for k, f in enumerate(bgr):
        f[..., 0], f[..., 2] = 200, 10 * k  # blue, and a red that counts the frames
    write_video(cv2, tmp_path / "colour.avi", bgr, 10.0)
    camera = OpenCvCamera(str(tmp_path / "colour.avi"), RGB, "src")
    try:
        first = camera.feed.wait_first(30.0)
    finally:
        camera.close()
    assert first.shape == (12, 16, 3) and first[0, 0, 2] == 200 and first[0, 0, 1] == 0
    for target, words in ((DEPTH, "a 'bgr8' picture for a depth block"),
                          (FrameTarget((10, 16), "rgb", "front"), "expects 10 x 16")):  # fmt: skip
        camera = OpenCvCamera(str(tmp_path / "colour.avi"), target, "--camera-source x")
        try:
            with pytest.raises(CameraError) as err:
                camera.feed.wait_first(30.0)
        finally:
            camera.close()
        assert words in one_line(err)
    with pytest.raises(CameraError, match=r"^src: OpenCV cannot open '.*missing.avi'$"):
        OpenCvCamera(str(tmp_path / "missing.avi"), RGB, "src")


# ---------------------------------------------------------------------- RealSense
def test_realsense_without_a_device_or_recording_is_refused_in_one_line(tmp_path):
    rs = pytest.importorskip("pyrealsense2", reason="the extra 'realsense' is missing")
    if len(rs.context().query_devices()):
        pytest.skip("a RealSense is connected here: the refusal needs none")
    from sim2real.deploy.backends.camera.realsense_source import RealSenseCamera

    with pytest.raises(CameraError) as err:
        RealSenseCamera("", DEPTH, "--camera-source d=realsense:")
    assert one_line(err).endswith("no RealSense device is connected (connected: none)")
    with pytest.raises(CameraError) as err:
        RealSenseCamera(str(tmp_path / "none.bag"), DEPTH, "src")
    assert one_line(err) == f"src: no such recording '{tmp_path / 'none.bag'}'"


def test_a_realsense_recording_plays_as_a_camera_in_metres_by_its_depth_unit(tmp_path):
    """A bag written here in librealsense's own layout (tests/realsense_bag.py), played back by
    pyrealsense2: a D405-like depth unit of 0.1 mm read from the recording, its stamps' spacing
    kept, a block of another resolution refused."""
    pytest.importorskip("pyrealsense2", reason="the extra 'realsense' is missing")
    pytest.importorskip("rosbags", reason="rosbags (the extra 'dev') writes the recording")
    from sim2real.deploy.backends.camera.realsense_source import RealSenseCamera
    from tests.realsense_bag import write_depth_bag

    units = [np.full((12, 16), 10000 + 1000 * k, np.uint16) for k in range(5)]
    units[2][3, 3] = 0  # no stereo match
    stamps = write_depth_bag(tmp_path / "walk.bag", units, 30.0, 1e-4)
    camera = RealSenseCamera(str(tmp_path / "walk.bag"), DEPTH, "--camera-source d=realsense:b")
    got, frame = [], NS(time=np.zeros(1))
    try:
        assert camera.depth_scale == pytest.approx(1e-4)
        camera.feed.wait_first(30.0)
        end = time.monotonic() + 30.0
        while time.monotonic() < end and not (got and got[-1][0][0, 0] >= 1.39):
            take(camera, frame)
            if not np.isnan(frame.depth_stamp[0]):
                got.append((frame.depth_image[0].copy(), float(frame.depth_stamp[0])))
            time.sleep(0.005)
    finally:
        camera.close()
    assert len(got) >= 2 and camera.domain == "system_time"
    index = [round((img[0, 0] - 1.0) / 0.1) for img, _ in got]
    for (img, stamp), k in zip(got, index, strict=True):
        np.testing.assert_allclose(img, units[k] * 1e-4, rtol=1e-6)  # metres; the hole still 0
        assert stamp - got[0][1] == pytest.approx((stamps[k] - stamps[index[0]]) / 1000, abs=1e-6)
    camera = RealSenseCamera(str(tmp_path / "walk.bag"), FrameTarget((10, 16), "depth", "d"), "src")
    try:
        with pytest.raises(CameraError) as err:
            camera.feed.wait_first(30.0)
    finally:
        camera.close()
    assert "a frame of 12 x 16 pixels; the policy's image block expects 10 x 16" in one_line(err)


# ---------------------------------------------------------------------- ROS 2
def image_msg(encoding, array, stamp):
    from sensor_msgs.msg import Image

    a = np.ascontiguousarray(array)
    msg = Image(encoding=encoding, height=a.shape[0], width=a.shape[1], is_bigendian=0)
    msg.step = a.nbytes // a.shape[0]
    msg.data = a.tobytes()
    msg.header.stamp = stamp
    return msg


def test_image_fields_are_read_with_padded_rows_and_big_endian_depth():
    from sim2real.deploy.ros2.camera import image_from_msg

    mm = np.arange(12 * 16, dtype=np.uint16).reshape(12, 16)
    padded = np.zeros((12, 40), np.uint8)  # 32 bytes of pixels, 8 of padding per row
    padded[:, :32] = mm.astype(">u2").view(np.uint8).reshape(12, 32)
    out = image_from_msg("16UC1", 12, 16, 40, True, padded.tobytes(), "t")
    np.testing.assert_array_equal(out, mm)
    with pytest.raises(CameraError, match=r"expected step >= 32 and 12 x step bytes$"):
        image_from_msg("16UC1", 12, 16, 32, False, b"\0" * 100, "t")
    with pytest.raises(CameraError, match=r"encoding 'bayer_rggb8' is not read"):
        image_from_msg("bayer_rggb8", 12, 16, 16, False, b"\0" * 192, "t")


def published(sub, msgs, pub, fill_frame):
    """Publish ``msgs`` one at a time, each until the subscriber took it; [(image, stamp)]."""
    got = []
    for msg in msgs:
        before = sub.feed.received
        end = time.monotonic() + 20.0
        while sub.feed.received == before and time.monotonic() < end:
            pub.publish(msg)
            time.sleep(0.05)
        assert sub.feed.received > before, "no frame arrived"
        take(sub, fill_frame)
        image, stamp = sub.feed.fields
        got.append((getattr(fill_frame, image)[0].copy(), float(getattr(fill_frame, stamp)[0])))
    return got


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1", "png"])
def test_a_ros2_depth_topic_gives_metres_aged_by_the_header_stamps_written(ros_domain, encoding):  # noqa: F811
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import CompressedImage, Image

    from sim2real.deploy.ros2.camera import ImageSubscriber
    from sim2real.deploy.ros2.context import NodeThread

    cv2 = None
    if encoding == "png":
        cv2 = pytest.importorskip("cv2", reason="OpenCV decodes CompressedImage")
    topic = "/head/depth" + ("/compressed" if encoding == "png" else "")
    sub = ImageSubscriber(topic, DEPTH, f"--camera-source head_depth=ros2:{topic}")
    frame = NS(time=np.zeros(1))
    try:
        with NodeThread("camera_driver") as driver:
            kind = CompressedImage if encoding == "png" else Image
            pub = driver.node.create_publisher(kind, topic, 10)
            now = driver.node.get_clock().now().nanoseconds
            msgs, want = [], []
            for k, back in enumerate((0.5, 0.3)):  # stamped 0.5 s and 0.3 s before now
                ns = now - int(back * 1e9)
                stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
                mm = np.full((12, 16), 800 + 100 * k, np.uint16)
                want.append(mm / 1000.0)
                if encoding == "16UC1":
                    msgs.append(image_msg("16UC1", mm, stamp))
                elif encoding == "32FC1":
                    msgs.append(image_msg("32FC1", (mm / 1000.0).astype(np.float32), stamp))
                else:
                    msg = CompressedImage(format="16UC1; png compressed")
                    msg.data = cv2.imencode(".png", mm)[1].tobytes()
                    msg.header.stamp = stamp
                    msgs.append(msg)
            got = published(sub, msgs, pub, frame)
    finally:
        sub.close()
    for (img, _), w in zip(got, want, strict=True):
        np.testing.assert_allclose(img, w, rtol=1e-6)
    # the two frames' capture times are 0.2 s apart, as their header stamps say
    # (to the few us between the callback's reads of the monotonic and the ROS clock)
    assert got[1][1] - got[0][1] == pytest.approx(0.2, abs=5e-3)
    assert sub.feed.last_age >= 0.3  # at least as old as its stamp said when it was written


def test_a_ros2_colour_jpeg_and_a_wrong_encoding(ros_domain):  # noqa: F811
    cv2 = pytest.importorskip("cv2", reason="OpenCV decodes CompressedImage")
    from sensor_msgs.msg import CompressedImage, Image

    from sim2real.deploy.ros2.camera import ImageSubscriber
    from sim2real.deploy.ros2.context import NodeThread

    rgb_sub = ImageSubscriber("/front/compressed", RGB, "front=ros2:/front/compressed")
    depth_sub = ImageSubscriber("/front_raw", DEPTH, "head_depth=ros2:/front_raw")
    frame = NS(time=np.zeros(1))
    try:
        with NodeThread("camera_driver") as driver:
            bgr = np.zeros((12, 16, 3), np.uint8)
            bgr[..., 2] = 250  # red in OpenCV's order
            msg = CompressedImage(format="jpeg")
            msg.data = cv2.imencode(".jpg", bgr)[1].tobytes()
            pub = driver.node.create_publisher(CompressedImage, "/front/compressed", 10)
            (img, stamp), = published(rgb_sub, [msg], pub, frame)  # fmt: skip
            assert img.shape == (12, 16, 3) and abs(int(img[0, 0, 0]) - 250) <= 3  # red first
            assert stamp <= frame.time[0]  # an unstamped frame: stamped when it arrived
            raw = driver.node.create_publisher(Image, "/front_raw", 10)
            wrong = image_msg("rgb8", bgr, msg.header.stamp)
            end = time.monotonic() + 20.0
            while True:  # until it arrived (before: "no frame within 0.2 s")
                raw.publish(wrong)
                with pytest.raises(CameraError) as err:
                    depth_sub.feed.wait_first(0.2)
                if "no frame" not in str(err.value) or time.monotonic() > end:
                    break
    finally:
        rgb_sub.close()
        depth_sub.close()
    assert "a 'rgb8' picture for a depth block" in one_line(err)


# ---------------------------------------------------------------------- deploy-run
def test_deploy_run_refuses_camera_sources_that_do_not_fit_in_one_line(go2, tmp_path, capsys):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    policy = depth_policy(go2, tmp_path)  # its camera: head_depth, 12 x 16
    base = ["--robot", "go2", "--policy", str(policy.path), "--duration", "0.1"]
    for extra, words in (
        (
            ["--camera-source", "head_depth=usb:0"],
            "--camera-source 'head_depth=usb:0': unknown camera kind 'usb'",
        ),
        (
            ["--camera-source", "chin=opencv:x.mkv"],
            "--camera-source chin=opencv:x.mkv: a hardware camera delivers on the wall clock",
        ),
        (
            ["--camera-source", "chin=opencv:x.mkv", "--realtime"],
            "the policy has no camera 'chin' (its images entries name ['head_depth'])",
        ),
        (
            ["--camera-source", f"head_depth=opencv:{tmp_path / 'x.mkv'}", "--realtime"],
            OPENCV_MISSING or "OpenCV cannot open",
        ),
    ):
        code = deploy_run_main(base + extra)
        err = capsys.readouterr().err.strip().splitlines()
        errors = [line for line in err if "error" in line]
        assert code == 3 and len(errors) == 1 and words in errors[0], err


@pytest.mark.wallclock
def test_deploy_run_feeds_the_policy_from_a_recorded_video(go2, cv2, tmp_path, capsys):
    """The Go2 in the plant on the wall clock, its depth policy fed from a 16-bit video (the
    plant renders nothing: the shipped Go2 has no head camera)."""
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main

    policy = depth_policy(go2, tmp_path)
    write_video(cv2, tmp_path / "d.mkv", [np.full((12, 16), 1200, np.uint16)] * 10, 25.0, True)
    report = tmp_path / "report.json"
    code = deploy_run_main(
        ["--robot", "go2", "--policy", str(policy.path), "--duration", "0.3", "--realtime",
         "--camera-source", f"head_depth=opencv:{tmp_path / 'd.mkv'},loop", "--report", str(report)]
    )  # fmt: skip
    out, err = capsys.readouterr()
    assert code != 3, out + err
    assert "deploy-run: camera 'head_depth' from opencv:" in err
    camera = json.loads(report.read_text())["camera"]
    assert camera["hardware"]["taken"] >= 1 and camera["frames_taken"][0] >= 1
    assert camera["hardware"]["stamp_clock"] == "file"


def test_a_camera_policy_on_a_backend_that_renders_nothing_needs_a_camera_source(go2, tmp_path):
    from sim2real.deploy.cli.exteroception import attach_camera

    policy = depth_policy(go2, tmp_path)
    args = NS(backend="servo", camera_source=[], camera_rate=None, camera_latency=None,
              camera_faults="none", seed=0, realtime=True)  # fmt: skip
    robot_bus = NS()  # a backend with no plant (no models, no datas) and no camera of its own
    with pytest.raises(ValueError) as err:
        attach_camera(args, robot_bus, policy.spec)
    assert one_line(err) == (
        "the policy reads camera 'head_depth' (depth); --backend servo has none: give "
        "--camera-source head_depth=KIND:WHERE (opencv:INDEX, realsense:SERIAL, ros2:/TOPIC; "
        "docs/cameras.md)"
    )
