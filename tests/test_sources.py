"""Camera sources against real OpenCV files, real folders and a real TCP camera server."""

from __future__ import annotations

import queue
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.config import CameraConfig
from companion.sources.base import CameraError, CameraTimeout, EndOfStream, Frame
from companion.sources.colour_open import open_camera, open_source, parse_source
from companion.sources.folder import write_frame
from companion.sources.reopen import ReopeningSource
from companion.sources.sim import SimSource, encode_sim_frame
from tests.badimages import avi_with_a_damaged_frame, huge_jpeg

# Clock mapping: time.time() and time.monotonic() are sampled a few microseconds
# apart; 50 ms allows for a loaded 2-core test machine between the two samples.
CLOCK_TOL_S = 0.05


def _marked(i: int, size: tuple[int, int] = (160, 120)) -> np.ndarray:
    """A frame whose white square's column encodes i (survives JPEG/MJPG)."""
    w, h = size
    image = np.full((h, w, 3), 40, np.uint8)
    x = 10 + 20 * i
    image[40:80, x : x + 16] = 255
    return image


def _mark_of(image: np.ndarray) -> int:
    cols = np.flatnonzero(image[60, :, 1] > 160)
    return round(float(cols.min() - 10) / 20)


# -- video file -------------------------------------------------------------------


def test_video_file_frames_timestamps_and_end(tmp_path: Path) -> None:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 120))
    assert writer.isOpened()
    for i in range(5):
        writer.write(_marked(i))
    writer.release()

    before = time.monotonic()
    source = open_source(CameraConfig(source=f"file:{path}", fps=25.0))
    frames = [source.read(1.0) for _ in range(5)]
    with pytest.raises(EndOfStream):
        source.read(1.0)
    source.close()
    source.close()  # safe twice

    assert [f.index for f in frames] == [0, 1, 2, 3, 4]
    assert [_mark_of(f.image) for f in frames] == [0, 1, 2, 3, 4]
    assert frames[0].image.shape == (120, 160, 3)
    # The file's own 10 fps, not the configured 25: 0.1 s apart on both clocks.
    assert np.allclose(np.diff([f.t_mono_s for f in frames]), 0.1, atol=1e-9)
    assert np.allclose(np.diff([f.t_unix_s for f in frames]), 0.1, atol=1e-9)
    assert before <= frames[0].t_mono_s <= time.monotonic()


def test_a_damaged_frame_is_skipped_and_the_video_goes_on(tmp_path: Path) -> None:
    """The frames after a damaged one are read, at their own times; the damaged one is
    counted. Before, a damaged frame ended the video as if it were its last."""
    path = tmp_path / "damaged.avi"
    avi_with_a_damaged_frame(path, [_marked(i) for i in range(8)], 3)
    source = open_source(CameraConfig(source=f"file:{path}"))
    frames = []
    with pytest.raises(EndOfStream, match="after 8 frames"):
        while True:
            frames.append(source.read(0.0))
    source.close()
    assert [f.index for f in frames] == [0, 1, 2, 4, 5, 6, 7]
    assert [_mark_of(f.image) for f in frames] == [0, 1, 2, 4, 5, 6, 7]
    assert frames[3].t_unix_s - frames[0].t_unix_s == pytest.approx(0.4)  # 4 frames at 10/s
    assert source.frames_corrupt == 1


def test_missing_or_unreadable_file_is_a_camera_error(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="no such file"):
        open_source(CameraConfig(source=f"file:{tmp_path / 'nope.avi'}"))
    junk = tmp_path / "junk.avi"
    junk.write_bytes(b"not a video at all" * 10)
    with pytest.raises(CameraError, match="not a video"):
        open_source(CameraConfig(source=f"file:{junk}"))


# -- frames folder ----------------------------------------------------------------


def test_frames_folder_sorted_by_time_with_bad_files_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    stamps_us = [1_700_000_002_000_000, 1_700_000_000_500_000, 1_700_000_001_250_000]
    for i, t_us in enumerate(stamps_us):
        cv2.imwrite(str(tmp_path / f"{t_us}.png"), _marked(i))
    (tmp_path / "1700000001000000.jpg").write_bytes(b"\xff\xd8 broken jpeg")
    (tmp_path / "1700000001100000.jpg").write_bytes(huge_jpeg())  # OpenCV raises on it
    # Cut short (OpenCV decodes both, grey below the cut), under each other's suffix:
    # judged by their bytes, not their names.
    png = cv2.imencode(".png", _marked(3))[1].tobytes()
    jpeg = cv2.imencode(".jpg", _marked(4))[1].tobytes()
    (tmp_path / "1700000001200000.jpg").write_bytes(png[: len(png) // 2])
    (tmp_path / "1700000001300000.png").write_bytes(jpeg[: len(jpeg) // 2])
    (tmp_path / "notes.txt").write_text("ignored")
    (tmp_path / "frame_12.png").write_bytes(b"ignored: not <unix_us>.png")

    offset = time.monotonic() - time.time()
    source = open_source(CameraConfig(source=f"frames:{tmp_path}"))
    frames = [source.read(0.0) for _ in range(3)]
    with pytest.raises(EndOfStream):
        source.read(0.0)
    source.close()

    assert [f.t_unix_s for f in frames] == [t / 1e6 for t in sorted(stamps_us)]
    assert [_mark_of(f.image) for f in frames] == [1, 2, 0]  # time order, not name order
    assert "1700000001200000.jpg is a truncated PNG" in caplog.text
    assert "1700000001300000.png is a truncated JPEG" in caplog.text
    for f in frames:
        assert f.t_mono_s - f.t_unix_s == pytest.approx(offset, abs=CLOCK_TOL_S)
    assert frames[1].t_mono_s - frames[0].t_mono_s == pytest.approx(0.75, abs=1e-6)


def test_write_frame_round_trips_through_the_folder_source(tmp_path: Path) -> None:
    frame = Frame(_marked(3), t_mono_s=10.0, t_unix_s=1_700_000_123.456789, index=0)
    path = write_frame(tmp_path, frame, ext="png")
    assert path.name == "1700000123456789.png"
    back = open_source(CameraConfig(source=f"frames:{tmp_path}")).read(0.0)
    assert back.t_unix_s == pytest.approx(frame.t_unix_s, abs=1e-6)
    assert np.array_equal(back.image, frame.image)  # PNG is lossless


def test_empty_or_missing_folder_is_a_camera_error(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="holds no frames"):
        open_source(CameraConfig(source=f"frames:{tmp_path}"))
    with pytest.raises(CameraError, match="no such folder"):
        open_source(CameraConfig(source=f"frames:{tmp_path / 'gone'}"))


# -- simulated camera over TCP ----------------------------------------------------


class CameraServer:
    """A real TCP camera server speaking the scenarios' wire format."""

    def __init__(self, port: int = 0) -> None:
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", port))
        self.listener.listen(1)
        self.port = self.listener.getsockname()[1]
        self.outgoing: queue.Queue[bytes | None] = queue.Queue()
        self.connected = threading.Event()
        self.conn: socket.socket | None = None
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        try:
            conn, _ = self.listener.accept()
        except OSError:
            return  # listener closed before anyone connected
        self.conn = conn
        self.connected.set()
        while (data := self.outgoing.get()) is not None:
            try:
                conn.sendall(data)
            except OSError:
                return
        conn.close()

    def send_frame(self, image: np.ndarray, t_unix_s: float) -> None:
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok
        self.outgoing.put(encode_sim_frame(jpeg.tobytes(), t_unix_s))

    def stop(self) -> None:
        self.listener.close()
        self.outgoing.put(None)
        self.thread.join(5.0)


@pytest.fixture
def server() -> Iterator[CameraServer]:
    srv = CameraServer()
    yield srv
    srv.stop()


def test_sim_frames_carry_the_capture_time(server: CameraServer) -> None:
    source = open_source(CameraConfig(source=f"sim:127.0.0.1:{server.port}"))
    assert server.connected.wait(5.0)
    t_capture = time.time() - 0.25  # rendered a quarter second ago
    server.send_frame(_marked(2, (640, 480)), t_capture)
    frame = source.read(5.0)
    source.close()
    source.close()
    assert frame.image.shape == (480, 640, 3)
    assert _mark_of(frame.image) == 2
    assert frame.t_unix_s == pytest.approx(t_capture, abs=1e-6)
    # 0.25 s before arrival on the monotonic clock as well.
    assert time.monotonic() - frame.t_mono_s == pytest.approx(0.25, abs=CLOCK_TOL_S + 0.2)
    assert frame.t_mono_s - frame.t_unix_s == pytest.approx(
        time.monotonic() - time.time(), abs=CLOCK_TOL_S
    )


def test_sim_timeout_then_newest_frame_wins(server: CameraServer) -> None:
    source = SimSource("127.0.0.1", server.port)
    assert server.connected.wait(5.0)
    with pytest.raises(CameraTimeout):
        source.read(0.05)
    t0 = time.time()
    for i in range(3):
        server.send_frame(_marked(i), t0 + i)
    # Wait on the grabber's own condition until it has all three; it keeps the newest.
    with source._cond:
        assert source._cond.wait_for(lambda: source.frames_grabbed == 3, timeout=5.0)
    frame = source.read(1.0)
    with pytest.raises(CameraTimeout):
        source.read(0.05)  # the two older frames were dropped, not queued
    source.close()
    assert source.frames_dropped == 2
    assert _mark_of(frame.image) == 2
    assert frame.index == 2


def test_sim_corrupt_jpeg_is_skipped_and_stream_stays_in_step(server: CameraServer) -> None:
    source = SimSource("127.0.0.1", server.port)
    assert server.connected.wait(5.0)
    server.outgoing.put(encode_sim_frame(b"\xff\xd8 not really a jpeg", time.time()))
    server.outgoing.put(encode_sim_frame(huge_jpeg(), time.time()))
    frame_2 = _marked(2)
    server.send_frame(frame_2, time.time())
    frame = source.read(5.0)
    source.close()
    assert _mark_of(frame.image) == 2
    assert frame.index == 2
    assert source.frames_corrupt + source.frames_dropped == 2


def test_sim_impossible_length_is_a_camera_error(server: CameraServer) -> None:
    source = SimSource("127.0.0.1", server.port)
    assert server.connected.wait(5.0)
    server.outgoing.put(b"\xff\xff\xff\xff" + b"\x00" * 64)
    with pytest.raises(CameraError, match="out of step"):
        source.read(5.0)
    source.close()


def test_sim_nobody_listening_is_a_camera_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound, never listening: connection refused
        with pytest.raises(CameraError, match="cannot connect"):
            SimSource("127.0.0.1", port)


def _first_frame(camera: ReopeningSource, within_s: float) -> Frame | None:
    """The first frame within ``within_s``; a CameraError meanwhile (down, backing
    off, reopening) is status, not a crash, so reading goes on."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            return camera.read(deadline - time.monotonic())
        except CameraError:
            continue
    return None


def test_reopen_after_the_server_goes_away_and_comes_back() -> None:
    first = CameraServer()
    port = first.port
    camera = ReopeningSource(
        lambda: SimSource("127.0.0.1", port), max_backoff_s=0.2, initial_backoff_s=0.05
    )
    with pytest.raises(CameraTimeout):
        camera.read(0.1)  # connected, nothing sent yet
    assert first.connected.wait(5.0)
    first.send_frame(_marked(0), time.time())
    assert _mark_of(camera.read(5.0).image) == 0
    assert camera.healthy

    first.stop()  # the server vanishes
    with pytest.raises(CameraError) as down:
        camera.read(0.3)
    assert not isinstance(down.value, CameraTimeout)
    assert "camera down" in str(down.value)
    assert not camera.healthy
    failures = camera.failures
    assert failures >= 2  # the lost connection, then refused reconnects

    second = CameraServer(port)  # back on the same port
    try:
        second.send_frame(_marked(4), time.time())
        frame = _first_frame(camera, 5.0)
        assert frame is not None and _mark_of(frame.image) == 4
        assert camera.healthy
        assert camera.opens == 2
    finally:
        camera.close()
        camera.close()
        second.stop()


def test_a_live_camera_that_connects_but_stays_silent_is_reopened() -> None:
    """A camera server that accepts the companion and then sends nothing (a hung
    camera process) is noticed after ``stall_timeout_s`` and reopened, as the
    companion's own configuration opens it; the second connection's frame arrives."""
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    held: list[socket.socket] = []
    ok, jpeg = cv2.imencode(".jpg", _marked(3))
    assert ok

    def serve() -> None:
        for n in range(2):
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            held.append(conn)  # the first stays open and silent
            if n == 1:
                conn.sendall(encode_sim_frame(jpeg.tobytes(), time.time()))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    camera = open_camera(
        CameraConfig(
            source=f"sim:127.0.0.1:{port}",
            width_px=160,  # the marked frames' size
            height_px=120,
            stall_timeout_s=0.5,
            reopen_max_backoff_s=0.2,
        )
    )
    try:
        frame = _first_frame(camera, 10.0)  # after "no frame for 0.5 s" and the reopen
        assert frame is not None and _mark_of(frame.image) == 3
        assert camera.opens == 2 and len(held) == 2
    finally:
        camera.close()
        listener.close()
        for conn in held:
            conn.close()
        thread.join(5.0)


def test_a_recording_is_never_reopened_for_silence(tmp_path: Path) -> None:
    camera = open_camera(CameraConfig(source=f"frames:{tmp_path}", stall_timeout_s=0.5))
    assert camera._stall_timeout_s is None
    assert open_camera(CameraConfig(source="sim", stall_timeout_s=0.0))._stall_timeout_s is None


def test_reopening_passes_end_of_stream_through(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "1700000000000000.png"), _marked(0))
    camera = open_camera(CameraConfig(source=f"frames:{tmp_path}"))
    assert camera.read(1.0).index == 0
    with pytest.raises(EndOfStream):
        camera.read(1.0)
    camera.close()


def test_the_camera_gives_frames_at_its_configured_size(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The camera model describes camera.width_px x height_px; a recording or a camera
    at another size of that aspect is resized (said once), another aspect is named."""
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"17000000000{i}0000.png"), _marked(i, (1280, 960)))
    camera = open_camera(CameraConfig(source=f"frames:{tmp_path}"))
    with caplog.at_level("WARNING"):
        frames = [camera.read(1.0) for _ in range(3)]
    camera.close()
    assert [f.image.shape for f in frames] == [(480, 640, 3)] * 3
    assert [f.index for f in frames] == [0, 1, 2]
    said = [r.getMessage() for r in caplog.records if "resized to it" in r.getMessage()]
    assert len(said) == 1 and "1280x960" in said[0], said
    wide = tmp_path / "wide"
    wide.mkdir()
    cv2.imwrite(str(wide / "1700000000000000.png"), _marked(0, (1280, 720)))
    with pytest.raises(
        CameraError, match="frames are 1280x720, the camera is configured for 640x480"
    ):
        from companion.sources.size import SizedSource

        SizedSource(open_source(CameraConfig(source=f"frames:{wide}")), 640, 480).read(1.0)


# -- source strings and unavailable cameras ---------------------------------------


@pytest.mark.parametrize(
    ("text", "kind", "target", "port"),
    [
        ("sim", "sim", "127.0.0.1", 5600),
        ("sim:10.0.0.5:7000", "sim", "10.0.0.5", 7000),
        ("device:2", "device", "2", 0),
        ("/dev/video3", "device", "3", 0),
        (
            "gstreamer:libcamerasrc ! videoconvert ! appsink",
            "gstreamer",
            "libcamerasrc ! videoconvert ! appsink",
            0,
        ),
        ("rtsp://cam.local:554/stream", "url", "rtsp://cam.local:554/stream", 0),
        ("file:/tmp/x.mp4", "file", "/tmp/x.mp4", 0),
        ("frames:/data/run1", "frames", "/data/run1", 0),
        ("picamera2", "picamera2", "", 0),
    ],
)
def test_parse_source(text: str, kind: str, target: str, port: int) -> None:
    spec = parse_source(text)
    assert (spec.kind, spec.target, spec.port) == (kind, target, port)


@pytest.mark.parametrize("text", ["sim:nohost", "sim:h:99999", "device:x", "webcam", "file:"])
def test_bad_source_strings_say_what_is_allowed(text: str) -> None:
    with pytest.raises(CameraError, match="source"):
        parse_source(text)


def test_absent_device_and_unsupported_backends_are_clear_errors() -> None:
    with pytest.raises(CameraError, match="cannot open"):
        open_source(CameraConfig(source="device:63"))
    try:
        import picamera2  # noqa: F401
    except ImportError:
        with pytest.raises(CameraError, match="python3-picamera2"):
            open_source(CameraConfig(source="picamera2"))
    if "GStreamer:                   NO" in cv2.getBuildInformation():
        with pytest.raises(CameraError, match="without GStreamer"):
            open_source(CameraConfig(source="gstreamer:videotestsrc ! appsink"))
