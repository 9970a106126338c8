"""gphoto2 backend against a fake at the python-gphoto2 API boundary (no camera needed)."""

from __future__ import annotations

from types import SimpleNamespace

import gphoto2
import pytest

from brdfrig.rig.camera import Camera
from brdfrig.rig.errors import DeviceBusy, DeviceDisconnected, DeviceNotFound
from brdfrig.rig.gphoto import GphotoCamera, parse_choice


class FakeWidget:
    def __init__(self, choices):
        self.choices, self.value = choices, None

    def get_choices(self):
        return iter(self.choices)

    def set_value(self, value):
        assert value in self.choices
        self.value = value


class FakeConfig:
    def __init__(self, widgets):
        self.widgets = widgets

    def get_child_by_name(self, name):
        if name not in self.widgets:
            raise gphoto2.GPhoto2Error(gphoto2.GP_ERROR_BAD_PARAMETERS)
        return self.widgets[name]


class FakeWorld:
    """Scripted failures: ``script[method]`` is a list of error codes raised by successive calls (0 = succeed)."""

    def __init__(self, script=None, present=True):
        self.script = {k: list(v) for k, v in (script or {}).items()}
        self.present = present
        self.calls: list[str] = []
        self.widgets = {"shutterspeed": FakeWidget(["bulb", "30", "1", "0.5", "1/4", "1/125", "1/250", "1/4000"]),
                        "iso": FakeWidget(["Auto", "100", "200", "400"]),
                        "aperture": FakeWidget(["f/4", "f/5.6", "f/8", "f/11"])}
        self.applied: dict[str, str] = {}
        self.inits = 0

    def step(self, name):
        self.calls.append(name)
        codes = self.script.get(name)
        if codes:
            code = codes.pop(0)
            if code:
                raise gphoto2.GPhoto2Error(code)


class FakeCamera:
    world: FakeWorld

    def init(self):
        w = self.world
        w.step("init")
        if not w.present:
            raise gphoto2.GPhoto2Error(gphoto2.GP_ERROR_MODEL_NOT_FOUND)
        w.inits += 1

    def exit(self):
        self.world.calls.append("exit")

    def get_config(self):
        self.world.step("get_config")
        return FakeConfig(self.world.widgets)

    def set_config(self, config):
        self.world.step("set_config")
        self.world.applied = {k: w.value for k, w in config.widgets.items()}

    def capture(self, kind):
        assert kind == gphoto2.GP_CAPTURE_IMAGE
        self.world.step("capture")
        return SimpleNamespace(folder="/store_00010001/DCIM/100CANON", name="IMG_0001.CR2")

    def file_get(self, folder, name, kind):
        assert kind == gphoto2.GP_FILE_TYPE_NORMAL
        self.world.step("file_get")
        return SimpleNamespace(save=lambda path: open(path, "wb").write(b"RAWDATA" * 100))


def fake_gp(world: FakeWorld):
    cam_cls = type("Camera", (FakeCamera,), {"world": world})
    consts = {k: getattr(gphoto2, k) for k in dir(gphoto2) if k.startswith("GP_")}
    return SimpleNamespace(Camera=cam_cls, GPhoto2Error=gphoto2.GPhoto2Error, **consts)


def camera(world, **kw):
    sleeps = []
    cam = GphotoCamera(gp_module=fake_gp(world), retries=3, settle_s=0.25, sleep=sleeps.append, **kw)
    return cam, sleeps


def test_choices_parse():
    assert parse_choice("1/125") == pytest.approx(0.008)
    assert parse_choice("30.0000s") == 30.0
    assert parse_choice("f/5.6") == 5.6
    assert parse_choice("Auto") is None and parse_choice("bulb") is None


def test_settings_capture_and_download(tmp_path):
    world = FakeWorld()
    cam, sleeps = camera(world)
    with cam:
        assert isinstance(cam, Camera)
        cam.set_exposure(1 / 120, 180, 6.0)
        assert world.applied == {"shutterspeed": "1/125", "iso": "200", "aperture": "f/5.6"}
        assert cam.exposure == pytest.approx((1 / 125, 200, 5.6))
        path = cam.capture(tmp_path)
    assert path == tmp_path / "IMG_0001.CR2" and path.read_bytes() == b"RAWDATA" * 100
    assert sleeps == [] and world.inits == 1 and "exit" in world.calls
    assert [p.name for p in tmp_path.iterdir()] == ["IMG_0001.CR2"]  # no temporary left behind


def test_ptp_device_busy_after_a_setting_change_is_retried_with_settle_time(tmp_path):
    busy = gphoto2.GP_ERROR_CAMERA_BUSY
    world = FakeWorld({"set_config": [busy, busy, 0], "capture": [busy, 0]})
    cam, sleeps = camera(world)
    with cam:
        cam.set_exposure(0.5, 100, 8)
        cam.capture(tmp_path)
    assert world.calls.count("set_config") == 3 and world.calls.count("capture") == 2
    assert sleeps == [0.25, 0.25, 0.25]
    assert world.inits == 1  # busy is waited out, not re-initialised


def test_io_error_reinitialises_then_succeeds(tmp_path):
    world = FakeWorld({"file_get": [gphoto2.GP_ERROR_IO, gphoto2.GP_ERROR_IO_READ, 0]})
    cam, sleeps = camera(world)
    with cam:
        cam.set_exposure(0.5, 100, 8)
        path = cam.capture(tmp_path)
    assert path.exists()
    assert world.inits == 3 and cam.reinit_count == 2  # exit + init twice
    assert world.calls.count("capture") == 1  # the shot is downloaded again, not re-taken
    assert world.calls.count("exit") >= 3


def test_usb_claimed_by_another_process_gives_up_with_a_hint():
    world = FakeWorld({"init": [gphoto2.GP_ERROR_IO_USB_CLAIM] * 10})
    cam, sleeps = camera(world)
    with pytest.raises(DeviceBusy, match="another process"):
        cam.open()
    assert world.calls.count("init") == 4 and len(sleeps) == 3


def test_persistent_io_error_is_bounded():
    world = FakeWorld({"capture": [gphoto2.GP_ERROR_IO] * 10})
    cam, _ = camera(world)
    with cam, pytest.raises(DeviceDisconnected, match="re-initialisation"):
        cam.capture(".")
    assert world.calls.count("capture") == 4


def test_no_camera_is_reported_clearly():
    cam, sleeps = camera(FakeWorld(present=False))
    with pytest.raises(DeviceNotFound, match="no camera found"):
        cam.open()
    assert sleeps == []


def test_real_library_without_camera_says_no_camera_found():
    """The bundled libgphoto2 raises -105 with nothing plugged in; the backend must say so."""
    with pytest.raises(DeviceNotFound, match="no camera found"):
        GphotoCamera(retries=0).open()


@pytest.mark.parametrize("args, name", [((0, 100, 8), "exposure time"), ((-1, 100, 8), "exposure time"),
                                        ((0.1, 0, 8), "iso"), ((0.1, 100, float("nan")), "f_number")])
def test_impossible_exposure_names_the_setting(args, name):
    cam, _ = camera(FakeWorld())
    with cam, pytest.raises(ValueError, match=name):
        cam.set_exposure(*args)
