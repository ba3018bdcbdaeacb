"""Teacher registry: built-ins by name, in-process registration, and plugins via entry points."""

import sys
import textwrap

import pytest
import torch

import aes_planner.teachers as teachers
from aes_planner.teachers import (
    ENTRY_POINT_GROUP,
    CompositionTeacher,
    TeacherError,
    available_teachers,
    get_teacher,
    register_teacher,
)

PLUGIN = '''
import torch
from aes_planner.teachers import Teacher


class MeanBrightness(Teacher):
    """A toy third-party teacher: the map is the image pooled to 4x4, the score its mean."""

    name = "brightness"
    feature_channels = 3
    feature_size = (4, 4)

    def __init__(self, gain=1.0):
        super().__init__()
        self.gain = gain
        self.freeze()

    def features(self, images):
        return torch.nn.functional.adaptive_avg_pool2d(images, self.feature_size)

    def head(self, fmap):
        return self.gain * fmap.mean((1, 2, 3))


def not_a_teacher():
    return object()
'''


@pytest.fixture
def plugin_dist(tmp_path, monkeypatch):
    """An installed distribution on sys.path that declares teachers in our entry-point group."""
    (tmp_path / "toy_teacher_plugin.py").write_text(PLUGIN)
    info = tmp_path / "toy_teacher_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-teacher-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        textwrap.dedent(
            f"""
            [{ENTRY_POINT_GROUP}]
            brightness = toy_teacher_plugin:MeanBrightness
            broken = toy_teacher_plugin_missing:Nothing
            bogus = toy_teacher_plugin:not_a_teacher
            ven = toy_teacher_plugin:MeanBrightness
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("toy_teacher_plugin", None)


def test_default_is_composition():
    assert isinstance(get_teacher(), CompositionTeacher)
    assert available_teachers()[:2] == ["composition", "ven"]


def test_unknown_name_lists_what_exists():
    with pytest.raises(TeacherError, match="unknown teacher 'nope'; available: composition, ven"):
        get_teacher("nope")


def test_wrong_options_are_named():
    with pytest.raises(TeacherError, match=r"does not take the options \['weights'\]"):
        get_teacher("composition", weights="x.pt")


def test_plugin_teacher_through_entry_points(plugin_dist, caplog):
    assert "brightness" in available_teachers()
    t = get_teacher("brightness", gain=2.0)
    x = torch.full((2, 3, 8, 8), 0.25)
    assert torch.allclose(t.score(x), torch.full((2,), 0.5))
    assert t.explain(x)["score"].shape == (2,)
    # a plugin cannot take over a built-in name
    with pytest.raises(TeacherError, match="VEN needs its released weights"):
        get_teacher("ven")
    assert "shadow the built-in" in caplog.text


def test_broken_plugins_are_reported_as_such(plugin_dist):
    with pytest.raises(TeacherError, match="failed to import"):
        get_teacher("broken")
    with pytest.raises(TeacherError, match="returned object, not an aes_planner.teachers.Teacher"):
        get_teacher("bogus")


def test_register_in_process(monkeypatch):
    monkeypatch.setattr(teachers, "_REGISTERED", {})
    register_teacher("mine", lambda: CompositionTeacher())
    assert "mine" in available_teachers()
    assert isinstance(get_teacher("mine"), CompositionTeacher)
    with pytest.raises(TeacherError, match="built-in"):
        register_teacher("composition", CompositionTeacher)
    with pytest.raises(TeacherError, match="callable"):
        register_teacher("x", 3)
