"""The kernels' numba cache is keyed on all of the kernel package's sources: numba itself keys a
cached kernel on the file defining it only, so an edit to a shared helper module would leave the
stages' old machine code in use."""

from aes_planner.gaussians.kernels import drop_stale_cache


def test_cached_kernels_go_when_any_kernel_source_changes(tmp_path):
    (tmp_path / "common.py").write_text("A = 1\n")
    (tmp_path / "stage.py").write_text("from common import A\n")
    constants = tmp_path / "numerics.txt"
    constants.write_text("T_STOP = 1e-4\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    (cache / "stage.f-1.py311.nbi").write_bytes(b"old")

    drop_stale_cache(tmp_path, (constants,))  # no stamp yet: unknown provenance, dropped
    assert not list(cache.glob("*.nbi"))
    (cache / "stage.f-1.py311.nbi").write_bytes(b"fresh")
    drop_stale_cache(tmp_path, (constants,))  # nothing changed: kept
    assert (cache / "stage.f-1.py311.nbi").read_bytes() == b"fresh"

    (tmp_path / "common.py").write_text("A = 2\n")  # the helper changes, the stage's file does not
    drop_stale_cache(tmp_path, (constants,))
    assert not list(cache.glob("*.nb?"))
    (cache / "stage.f-1.py311.nbc").write_bytes(b"fresh")
    constants.write_text("T_STOP = 1e-3\n")  # a constant the kernels froze at compile time
    drop_stale_cache(tmp_path, (constants,))
    assert not list(cache.glob("*.nb?"))
