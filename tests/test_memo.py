"""The render memo (brdfrig.fit.memo): its budget and policy, and fits that reuse kept renders.

Oracle for the fits: the same fit with nothing kept (a budget of 0 bytes), which must be equal to the last bit;
a second fit of the same image must render nothing, and one of another image on the same pixels and lighting
must not render the roughness grid again (renders depend on the pixels, the lighting and the roughness, never on
the radiance fitted).
"""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.fit.memo import RENDERS, RenderMemo
from brdfrig.fit.scene import Scene

from conftest import PROBE_DIR


def _counted(value: np.ndarray, calls: list):
    def compute() -> np.ndarray:
        calls.append(1)
        return value.copy()

    return compute


def test_kept_arrays_are_computed_once_and_read_only():
    memo, calls = RenderMemo(1 << 20), []
    first = memo.get("a", _counted(np.arange(4.0), calls))
    again = memo.get("a", _counted(np.zeros(4), calls))
    assert again is first and len(calls) == 1 and "a" in memo
    np.testing.assert_array_equal(again, np.arange(4.0))
    with pytest.raises(ValueError, match="read-only"):
        first[0] = 1.0


def test_least_recently_used_goes_first_past_the_budget():
    memo, calls = RenderMemo(2 * 800), []  # room for two arrays of 100 float64
    for key in ("a", "b"):
        memo.get(key, _counted(np.zeros(100), calls))
    memo.get("a", _counted(np.zeros(100), calls))  # "a" is now the most recent
    memo.get("c", _counted(np.zeros(100), calls))
    assert len(calls) == 3 and "a" in memo and "c" in memo and "b" not in memo and len(memo) == 2
    big = memo.get("big", _counted(np.zeros(300), calls))
    assert big.flags.writeable and "big" not in memo and len(memo) == 2
    memo.clear()
    assert len(memo) == 0 and "a" not in memo


def test_second_sight_keeps_an_array_only_when_asked_again():
    memo, calls = RenderMemo(1 << 20, second_sight=True), []
    assert memo.first_sight("k") and not memo.first_sight("k")
    memo.get("j", _counted(np.ones(3), calls))
    assert "j" not in memo
    memo.get("j", _counted(np.ones(3), calls))
    memo.get("j", _counted(np.ones(3), calls))
    assert "j" in memo and len(calls) == 2
    assert not RenderMemo(1 << 20).first_sight("k")


def _scenes(size: int = 16):
    from brdfrig.evaluate.probes import probe_environment
    from brdfrig.fit.pbr import SheenBRDF
    from brdfrig.hdr.sphere import sphere_pixels

    if not PROBE_DIR.is_dir():
        pytest.skip("../shared/data/probes is absent")
    px = sphere_pixels((size, size), (size / 2, size / 2, size / 2))
    normals = np.ascontiguousarray(px.normals[px.weights > 0])
    env = probe_environment("grace", 32, PROBE_DIR)
    brdfs = (SheenBRDF([0.5, 0.3, 0.2], fuzz_color=[0.3, 0.3, 0.5], fuzz_roughness=0.5, specular_roughness=0.4),
             SheenBRDF([0.2, 0.4, 0.6], fuzz_color=[0.6, 0.2, 0.1], fuzz_roughness=0.7, specular_roughness=0.25))
    return [Scene(env, normals, b.predict(env, normals), np.ones(len(normals))) for b in brdfs]


def _fitters():
    from brdfrig.fit import microfacet, pbr_fit
    from brdfrig.fit.bivariate import fit_bivariate

    return {"microfacet": (lambda s: microfacet.fit_microfacet(s, lmax=0, max_pixels=150, progress=False),
                           "lobe_renders", microfacet.GRID_POINTS),
            "sheen": (lambda s: pbr_fit.fit_pbr(s, "sheen", max_pixels=150, progress=False), "renders",
                      pbr_fit.GRID_POINTS),
            "bivariate": (lambda s: fit_bivariate(s, max_pixels=150, progress=False), None, 0)}


@pytest.mark.parametrize("name", ["microfacet", "sheen", "bivariate"])
def test_fits_from_kept_renders_equal_fits_without_them(name, monkeypatch):
    fit, renders, grid = _fitters()[name]
    scenes = _scenes()
    RENDERS.clear()
    monkeypatch.setattr(RENDERS, "max_bytes", 0)
    alone = [fit([s]) for s in scenes]
    assert len(RENDERS) == 0
    monkeypatch.setattr(RENDERS, "max_bytes", 1 << 28)
    kept = [fit([scenes[0]]), fit([scenes[0]]), fit([scenes[1]])]
    assert len(RENDERS) > 0
    for (brdf, _), (want, _) in zip(kept, [alone[0], alone[0], alone[1]]):
        assert brdf.to_dict() == want.to_dict()
    if renders is not None:
        assert 0 < kept[0][1][renders] <= alone[0][1][renders]  # a fit also meets its own renders again
        assert kept[1][1][renders] == 0  # the same image again
        assert kept[2][1][renders] <= alone[1][1][renders] - grid  # another image: its roughness grid is kept
    RENDERS.clear()
