"""The versioned BRDF file: round trips, and clear errors for other versions and corrupt files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brdfrig.fit.brdffile import FORMAT_VERSION, load_brdf, save_brdf
from brdfrig.fit.models import make_linear_brdf
from brdfrig.fit.system import ModelSpec


def _random_model(kind: str, seed: int = 0):
    spec = ModelSpec(kind, 4, 3, bands=(0, 1, 2, 4))
    x = np.random.default_rng(seed).normal(size=(spec.n_unknowns, 3))
    return make_linear_brdf(spec, x)


@pytest.mark.parametrize("kind", ["diffuse", "lobe", "full"])
def test_round_trip_preserves_the_model_exactly(tmp_path, kind):
    brdf = _random_model(kind)
    report = {"chosen_model": kind, "rank": np.array([3, 3, 3]), "cond": float("inf")}
    path = save_brdf(tmp_path / "m.brdf.json", brdf, report)
    back, rep = load_brdf(path)
    assert back.model == kind and back.spec == brdf.spec
    np.testing.assert_array_equal(back.x, brdf.x)
    theta = np.radians([5.0, 40.0, 70.0])
    np.testing.assert_array_equal(back.evaluate(theta, theta[::-1], 1.0), brdf.evaluate(theta, theta[::-1], 1.0))
    assert rep["rank"] == [3, 3, 3] and rep["cond"] == "inf"
    doc = json.loads(path.read_text())
    assert doc["format"] == "brdfrig-brdf" and doc["version"] == FORMAT_VERSION
    assert "sh_basis" in doc["conventions"] and "written_utc" in doc["provenance"]
    assert [p.name for p in tmp_path.iterdir()] == ["m.brdf.json"]  # no temporary left


def test_microfacet_model_round_trips_through_the_registry(tmp_path):
    from brdfrig.fit.analytic import GGX
    from brdfrig.fit.microfacet import MicrofacetBRDF
    from brdfrig.fit.models import DiffuseBRDF
    from brdfrig.fit.system import ModelSpec

    analytic = GGX(alpha=[0.2, 0.3, 0.4], f0=[0.04, 0.05, 0.06], diffuse=[0.5, 0.4, 0.3], f90=1.0, diffuse_sigma=[0.0, 0.2, 0.4])
    series = DiffuseBRDF(ModelSpec("diffuse", 2, bands=(1, 2)), np.array([[0.01, 0.02, 0.03], [-0.01, 0.0, 0.01]]))
    theta = np.radians([10.0, 50.0])
    for brdf in (MicrofacetBRDF(analytic, series), MicrofacetBRDF(analytic)):
        back, _ = load_brdf(save_brdf(tmp_path / "mf.json", brdf, {}))
        np.testing.assert_allclose(back.evaluate(theta, theta, np.pi), brdf.evaluate(theta, theta, np.pi), rtol=1e-12)
    # the Lambertian-base layout of an older brdfrig: a clear error, not a crash
    doc = json.loads((tmp_path / "mf.json").read_text())
    doc["brdf"] = {"model": "microfacet", "alpha": 0.2, "f0": [0.04], "diffuse": [0.5], "f90": [1.0]}
    (tmp_path / "old.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="refit"):
        load_brdf(tmp_path / "old.json")


def test_other_version_and_corrupt_files_are_clear_errors(tmp_path):
    path = save_brdf(tmp_path / "a.json", _random_model("diffuse"), {})
    doc = json.loads(path.read_text())
    doc["version"] = FORMAT_VERSION + 1
    (tmp_path / "v.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="version 2 is not supported"):
        load_brdf(tmp_path / "v.json")
    (tmp_path / "c.json").write_text(path.read_text()[:-40])
    with pytest.raises(ValueError, match="corrupt JSON"):
        load_brdf(tmp_path / "c.json")
    (tmp_path / "f.json").write_text(json.dumps({"format": "something-else", "version": 1}))
    with pytest.raises(ValueError, match="not a brdfrig BRDF file"):
        load_brdf(tmp_path / "f.json")
    doc = json.loads(path.read_text())
    doc["brdf"]["coefficients"] = doc["brdf"]["coefficients"][:-1]
    (tmp_path / "s.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="corrupt BRDF file"):
        load_brdf(tmp_path / "s.json")
    doc["brdf"]["model"] = "plenoptic"
    (tmp_path / "m.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="unknown BRDF model"):
        load_brdf(tmp_path / "m.json")
    with pytest.raises(OSError):
        load_brdf(tmp_path / "missing.json")


def test_failed_write_leaves_nothing(tmp_path):
    # Arbitrary report objects are written as their text (brdfrig.fit.brdffile.jsonable); force the failure
    # at the final rename instead: the target is a directory.
    (tmp_path / "x.json").mkdir()
    with pytest.raises(OSError):
        save_brdf(tmp_path / "x.json", _random_model("lobe"), {"path": tmp_path})
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]
    assert list((tmp_path / "x.json").iterdir()) == []


def test_registry_reads_analytic_models_without_a_prior_import():
    # A fresh interpreter that imports only brdfrig.fit.brdf: the registry must import brdfrig.fit.analytic itself.
    import subprocess
    import sys

    from brdfrig.fit.analytic import GGX, BlinnPhong, Lambertian

    cases = [Lambertian([0.5, 0.4, 0.3]), BlinnPhong(diffuse=[0.3] * 3, specular=[0.2] * 3, exponent=[20.0] * 3),
             GGX(alpha=0.3, f0=[0.04] * 3, diffuse=[0.5, 0.4, 0.3])]
    script = (
        "import json, sys, numpy as np\n"
        "from brdfrig.fit.brdf import brdf_from_dict\n"
        "out = []\n"
        "for d in json.loads(sys.stdin.read()):\n"
        "    b = brdf_from_dict(d)\n"
        "    out.append([b.model, np.asarray(b.evaluate(0.4, 0.7, 2.0)).tolist()])\n"
        "print(json.dumps(out))\n"
    )
    run = subprocess.run([sys.executable, "-c", script], input=json.dumps([c.to_dict() for c in cases]),
                         capture_output=True, text=True, check=True)
    for brdf, (model, value) in zip(cases, json.loads(run.stdout)):
        assert model == brdf.model
        np.testing.assert_allclose(value, brdf.evaluate(0.4, 0.7, 2.0), rtol=1e-12)


def test_a_non_finite_parameter_is_never_written(tmp_path):
    """A BRDF whose description holds NaN (e.g. a fit gone wrong) is refused, naming the key; nothing is written."""
    from brdfrig.errors import InputError

    class Broken:
        def to_dict(self):
            return {"model": "ggx", "alpha": [0.3, float("nan"), 0.3]}

    with pytest.raises(InputError, match=r"b\.json: refusing to write a BRDF with a non-finite parameter \(brdf\.alpha\[1\]\)"):
        save_brdf(tmp_path / "b.json", Broken())
    assert not list(tmp_path.iterdir())
