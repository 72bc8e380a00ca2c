"""The rim-height profile of a drawn cup (sim.frames.earing): heights around the punch axis and
the harmonics that tell a rolled sheet's ears from a mesh's pattern."""

import numpy as np
import pytest

from sim.frames.earing import rim


def cup(theta_rest, height, axis=(0.002, -0.001)):
    """A rest disk edge at angles ``theta_rest`` around ``axis``, drawn into a cup wall whose
    rim heights are ``height``, the bottom at z = -0.03 (the punch moves along -z)."""
    r0, r1 = 0.03, 0.017
    ax = np.array([*axis, 0.0])
    rest = ax + np.column_stack([r0 * np.cos(theta_rest), r0 * np.sin(theta_rest),
                                 np.zeros_like(theta_rest)])
    cur = ax + np.column_stack([r1 * np.cos(theta_rest), r1 * np.sin(theta_rest),
                                -0.03 + height])
    bottom = ax + np.array([[0.0, 0.0, -0.03]])
    return np.vstack([rest, ax[None]]), np.vstack([cur, bottom])


def test_rim_heights_and_harmonics():
    """Four ears of 0.4 mm crest at 45 degrees and a six-fold 0.2 mm pattern crest at 10
    degrees on a 20 mm wall: each harmonic is recovered with its crest, whatever the uneven
    sampling (the least-squares fit is exact for a band-limited profile)."""
    rng = np.random.default_rng(3)
    th = np.sort(rng.uniform(0, 2 * np.pi, 90))
    h = 0.02 + 4e-4 * np.cos(4 * (th - np.pi / 4)) + 2e-4 * np.cos(6 * (th - np.radians(10)))
    rest, cur = cup(th, h)
    edge = np.arange(len(th))[::-1].copy()  # any order: the rim sorts by angle
    r = rim(rest, cur, edge, np.array([0.0, 0.0, -1.0]), np.array([0.002, -0.001, 0.0005]))
    np.testing.assert_allclose(r.angle, th, atol=1e-12)
    np.testing.assert_allclose(r.height, h, atol=1e-15)
    a4, c4 = r.harmonic(4)
    a6, c6 = r.harmonic(6)
    # a fit of exact data: round-off of the normal equations' QR, ~1e-16 of the 20 mm mean
    assert a4 == pytest.approx(4e-4, abs=1e-13)
    assert np.degrees(c4) == pytest.approx(45.0, abs=1e-7)
    assert a6 == pytest.approx(2e-4, abs=1e-13)
    assert np.degrees(c6) == pytest.approx(10.0, abs=1e-7)
    assert r.harmonic(2)[0] <= 1e-13
    assert r.earing == pytest.approx((h.max() - h.min()) / h.mean(), rel=1e-12)


def test_an_earing_made_by_the_mesh_says_so():
    """A review read 'Earing 11.8 %' beside a six-fold (mesh) harmonic of 0.859 mm and four
    ears of 0.141 mm: the earing's note (and the card's flag) says when the mesh's wave is the
    larger and makes at least half the rim's spread."""
    from sim.frames.summary import _mesh_earing

    assert _mesh_earing(0.5e-3, 0.1e-3, 1.2e-3) == ""  # a rolled sheet's ears: the sheet's
    # a blank without a lattice (MeshAdapt's isotropic cup: six-fold 0.065 mm, four-fold
    # 0.04, spread 1.03 mm): neither term is the spread, the note does not blame a lattice
    assert _mesh_earing(0.04e-3, 0.065e-3, 1.03e-3) == ""
    note = _mesh_earing(0.141e-3, 0.859e-3, 2.4e-3)
    assert "mostly the mesh's: its six-fold wave (0.859 mm) is larger than the four ears " \
           "(0.141 mm)" in note and 'mesh.mesher = "meshadapt"' in note
