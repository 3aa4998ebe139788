"""Specular NLOS from physics (issue 21 item 1): Fresnel coefficients, circular polarisation, the image method,
the materials of ITU-R P.2040 — each against a closed form or a hand computation."""

import numpy as np
import pytest

from features.site import Box, Origin, Site
from simulation.gnss.reflection import (antenna_xpr_db, circular_coefficients, fresnel_coefficients,
                                        reflection_loss_db, relative_permittivity, specular_fraction,
                                        specular_reflections)
from simulation.gnss.signal import Reflectors, SignalConfig, blockage
from simulation.site.geometry import boxes_array

L1_HZ = 1.57542e9


def test_fresnel_closed_forms():
    """Normal incidence Γ = ∓(√η − 1)/(√η + 1); Brewster angle tan θ_B = √η makes Γ_TM vanish; grazing → −1."""
    eta = 5.24
    te, tm = fresnel_coefficients(eta, 1.0)
    r = (np.sqrt(eta) - 1.0) / (np.sqrt(eta) + 1.0)
    assert complex(te).real == pytest.approx(-r) and complex(tm).real == pytest.approx(r)
    theta_b = np.arctan(np.sqrt(eta))
    _, tm_b = fresnel_coefficients(eta, np.cos(theta_b))
    assert abs(complex(tm_b)) < 1e-9
    te_g, tm_g = fresnel_coefficients(eta, 1e-6)
    assert complex(te_g).real == pytest.approx(-1.0, abs=1e-5) and complex(tm_g).real == pytest.approx(-1.0, abs=1e-4)
    # energy: |Γ|² ≤ 1 for a lossy dielectric at every angle
    c = np.linspace(0.01, 1.0, 50)
    te, tm = fresnel_coefficients(relative_permittivity("brick", L1_HZ), c)
    assert np.all(np.abs(te) <= 1.0) and np.all(np.abs(tm) <= 1.0)


def test_circular_polarisation_flips_on_metal_and_keeps_at_grazing_dielectric():
    metal = relative_permittivity("steel", L1_HZ)
    for c in (1.0, 0.5, 0.1):
        co, x = circular_coefficients(metal, c)
        assert abs(complex(co)) < 1e-3 and abs(complex(x)) == pytest.approx(1.0, abs=1e-3)
        # so the loss is the antenna's cross-polar rejection, whatever the angle
        assert float(reflection_loss_db(metal, c, 12.0)) == pytest.approx(12.0, abs=0.01)
    concrete = relative_permittivity("concrete", L1_HZ)
    co, x = circular_coefficients(concrete, 0.05)      # beyond Brewster: handedness kept
    assert abs(complex(co)) > 3 * abs(complex(x))
    co, x = circular_coefficients(concrete, 1.0)       # normal incidence: all flipped
    assert abs(complex(co)) < 1e-12 < abs(complex(x))
    # concrete at normal incidence, hand computation: |Γ|² = 0.156 → 8.1 dB, + XPR 10 dB on the LHCP → 18.1 dB
    assert float(reflection_loss_db(concrete, 1.0, 10.0)) == pytest.approx(18.1, abs=0.1)
    assert float(antenna_xpr_db(10.0, np.radians(30.0))) == pytest.approx(5.0)
    # Rayleigh roughness: a smooth face is all specular, σ_h = λ/4 at normal incidence almost none
    assert float(specular_fraction(0.0, 1.0, 0.19)) == 1.0 and float(specular_fraction(0.19 / 4, 1.0, 0.19)) < 0.01


def test_image_method_on_one_wall():
    """A wall 10 m east of the receiver (face x = 10, facing west), a satellite low in the west behind a building:
    the reflection off the wall arrives from the east with extra path 2·d·cos θᵢ = 2·10·cos(el)·|cos Δaz|."""
    wall = Box("firewall", "concrete", False, 10.0, 10.4, -30.0, 30.0, 10.0)
    boxes = boxes_array([wall])
    az, el = np.radians(270.0 + 20.0), np.radians(25.0)   # WNW
    r = specular_reflections(np.array([[0.0, 0.0]]), np.array([1.0]), np.array([az]), np.array([el]), boxes,
                             np.array([False]), np.array([relative_permittivity("concrete", L1_HZ)]),
                             np.array([0.01]), 10.0, 0.1903, np.array([10.0]))
    cos_i = np.cos(el) * abs(np.cos(np.radians(20.0)))
    assert r.box[0] == 0 and r.extra_m[0] == pytest.approx(2.0 * 10.0 * cos_i)
    assert float(r.loss_db[0]) == pytest.approx(float(reflection_loss_db(relative_permittivity("concrete", L1_HZ),
                                                                        cos_i, antenna_xpr_db(10.0, el))))
    assert 0.0 < r.k_lin[0] <= 10.0
    # a satellite in the east shines on the far face only: no reflection toward a receiver west of the wall
    r2 = specular_reflections(np.array([[0.0, 0.0]]), np.array([1.0]), np.array([np.radians(90.0)]),
                              np.array([el]), boxes, np.array([False]), np.array([4.0 + 0j]), np.array([0.01]), 10.0,
                              0.1903, np.array([10.0]))
    assert r2.box[0] == -1 and np.isinf(r2.loss_db[0])
    # a high satellite whose reflection point would lie above the 10 m wall top: none (10·tan 60° = 17 m > 10 m)
    r3 = specular_reflections(np.array([[0.0, 0.0]]), np.array([1.0]), np.array([np.radians(270.0)]),
                              np.array([np.radians(60.0)]), boxes, np.array([False]), np.array([4.0 + 0j]),
                              np.array([0.01]), 10.0, 0.1903, np.array([10.0]))
    assert r3.box[0] == -1
    # a kiosk between the receiver and the wall blocks the first leg: the ray toward the wall's specular point
    # (heading ENE) enters its south face at (2.75, 1.0), 2.4 m up, under its 5 m roof; its own faces reflect
    # nothing toward the receiver (the west face's specular point, y = 0.73, misses the face y ∈ [1, 3]; the
    # satellite does not light the south face)
    kiosk = Box("building", "steel", False, 2.0, 8.0, 1.0, 3.0, 5.0)
    both = boxes_array([wall, kiosk])
    eta2 = np.array([relative_permittivity("concrete", L1_HZ), relative_permittivity("steel", L1_HZ)])
    r4 = specular_reflections(np.array([[0.0, 0.0]]), np.array([1.0]), np.array([az]), np.array([el]), both,
                              np.array([False, False]), eta2, np.array([0.01, 0.01]), 10.0, 0.1903, np.array([10.0]))
    assert r4.box[0] == -1
    # moved 5 m north out of the way, the wall's reflection is back with the same extra path
    kiosk_n = Box("building", "steel", False, 2.0, 8.0, 6.0, 8.0, 5.0)
    r5 = specular_reflections(np.array([[0.0, 0.0]]), np.array([1.0]), np.array([az]), np.array([el]),
                              boxes_array([wall, kiosk_n]), np.array([False, False]), eta2, np.array([0.01, 0.01]),
                              10.0, 0.1903, np.array([10.0]))
    assert r5.box[0] == 0 and r5.extra_m[0] == pytest.approx(r.extra_m[0])


def test_blocked_satellite_arrives_by_the_strongest_of_diffraction_reflection_and_diffuse_scatter():
    """Receiver between a building (west, 5 m tall, blocking a low western satellite) and a steel tank (east): the
    tank reflects it — the incoming ray reaches the tank's face 3.2 m up and clears the building's roof (6.1 m at
    its face, by hand) — with the antenna's XPR as loss, stronger than 15-30 dB of diffuse scatter, so the signal
    is specular NLOS with the geometric extra path; without the tank, diffuse NLOS at the drawn loss."""
    building = Box("building", "concrete", False, -20.0, -2.0, -30.0, 30.0, 5.0)
    tank = Box("transformer", "steel", False, 6.0, 14.0, -4.0, 4.0, 6.0)
    az = np.array([[np.radians(270.0)]])
    el = np.array([[np.radians(20.0)]])
    site = Site("t", Origin(35.0, 115.0, 50.0), layout=(building, tank))
    boxes = boxes_array(site.layout)
    refl = Reflectors(np.array([relative_permittivity(b.material, L1_HZ) for b in site.layout]),
                      np.array([0.01, 0.01]), 8.0, np.array([10.0]))
    cfg = SignalConfig()
    b = blockage(np.array([[0.0, 0.0]]), np.array([1.0]), az, el, boxes, np.array([False, False]),
                 np.full((1, 2), 22.0), np.zeros((1, 2)), np.zeros((1, 2)), cfg, reflectors=refl)
    assert b.solid_blocked[0, 0] and b.nlos[0, 0] and b.specular[0, 0]
    assert b.loss_db[0, 0] == pytest.approx(float(antenna_xpr_db(8.0, np.radians(20.0))), abs=0.01)
    assert b.nlos_extra_m[0, 0] == pytest.approx(2.0 * 6.0 * np.cos(np.radians(20.0)))
    alone = Site("t", Origin(35.0, 115.0, 50.0), layout=(building,))
    b2 = blockage(np.array([[0.0, 0.0]]), np.array([1.0]), az, el, boxes_array(alone.layout), np.array([False]),
                  np.full((1, 1), 22.0), np.zeros((1, 1)), np.zeros((1, 1)), cfg,
                  reflectors=Reflectors(refl.eta[:1], refl.roughness_m[:1], 8.0, np.array([10.0])))
    assert b2.nlos[0, 0] and not b2.specular[0, 0] and b2.loss_db[0, 0] == pytest.approx(22.0)
    assert b2.nlos_k_lin[0, 0] == 0.0                                   # diffuse: Rayleigh
