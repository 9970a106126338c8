"""Identifiability from the lighting alone, against MATH.md's counting and the rank of pixel-assembled systems."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.fit.identifiability import analyse_lighting, scenes_needed
from brdfrig.fit.scene import Environment
from brdfrig.fit.shproject import project_environment
from brdfrig.fit.solvers import StreamedQR, solve
from brdfrig.fit.system import ModelSpec, design_block
from brdfrig.hdr.envmap import latlong_directions
from test_fit_scenes import probe_environment, rotations, sphere


@pytest.fixture
def grace(real_probes):
    return probe_environment({p.stem: p for p in real_probes}["grace"])


def _coeffs(envs, lmax):
    return [project_environment(e, lmax) for e in envs]


def test_one_scene_cannot_determine_the_full_model(grace):
    lmax = 6
    ident = analyse_lighting(_coeffs([grace], lmax), lmax, lmax)
    assert not ident.determined("full")
    assert ident.determined("diffuse") and ident.determined("lobe")
    assert ident.scenes_needed == scenes_needed(lmax) == 7
    assert "needs >= 7 scenes" in ident.models["full"]["reason"]
    assert ident.full_lmax_determined == 0  # band 0 alone is trivially separated
    # MATH.md pitfall 1: per order j one lighting coefficient per band per scene (two for j > 0).
    assert ident.order_rank.tolist() == [1] + [min(2, lmax - j + 1) for j in range(1, lmax + 1)]
    assert "UNDETERMINED" in ident.summary()


@pytest.mark.parametrize("count", [3, 4, 5, 12])
def test_rank_per_order_counts_scenes(grace, count):
    lmax = 4
    ident = analyse_lighting(_coeffs(rotations(grace, count), lmax), lmax, lmax)
    expected = [min(count, lmax + 1)] + [min(2 * count, lmax - j + 1) for j in range(1, lmax + 1)]
    assert ident.order_rank.tolist() == expected
    assert ident.determined("full") == (count >= lmax + 1)
    assert ident.full_lmax_determined == min(count - 1, lmax)
    # band l at order 0 is separated only when every band is (one row per scene)
    assert bool(ident.band_determined[lmax, 0]) == (count >= lmax + 1)


@pytest.mark.parametrize("count", [1, 3, 5])
def test_reported_rank_equals_rank_of_pixel_assembled_system(grace, count):
    lmax = pmax = 4
    envs = rotations(grace, count)
    coeffs = _coeffs(envs, lmax)
    ident = analyse_lighting(coeffs, lmax, pmax)
    normals, weights = sphere(64)
    keep = normals[:, 2] >= math.cos(math.radians(80))
    normals, weights = normals[keep], weights[keep]
    for kind in ("diffuse", "lobe", "full"):
        spec = ModelSpec(kind, lmax, pmax)
        qr = StreamedQR(spec.n_unknowns, 3)
        for c in coeffs:
            a = design_block(spec, c, normals)
            qr.add(a, np.zeros((len(normals), 3)), weights)
        rank = int(solve(qr, "joint").rank.min())
        assert ident.models[kind]["rank"] == rank, (kind, count)
        assert ident.models[kind]["unknowns"] == spec.n_unknowns
    assert ident.models["full"]["rank"] < ident.models["full"]["unknowns"] or count >= lmax + 1


def test_bands_without_lighting_energy_are_unobservable():
    """Uniform + dipole lighting (no energy above band 1): bands >= 2 are reported and dropped."""
    dirs, solid = latlong_directions(32, 64)
    dirs = dirs.reshape(-1, 3)
    rad = (1.0 + 0.5 * dirs[:, 1:2]) * np.array([[1.0, 0.8, 0.6]])
    env = Environment(dirs, rad, solid.reshape(-1))
    lmax = 6
    ident = analyse_lighting(_coeffs([env], lmax), lmax, lmax)
    assert ident.observable_bands == [0, 1]
    assert ident.unobservable_bands == [2, 3, 4, 5, 6]
    assert ident.models["diffuse"]["unknowns"] == 2 and ident.determined("diffuse")
    assert "no lighting energy" in ident.summary()
    assert ident.scenes_needed == 2
