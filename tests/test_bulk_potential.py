"""The flesh's bulk potential (``Material.bulk_potential``; docs/design.md, "Flesh"): kappa/2 (ln J)^2,
wface's default, or kappa/2 (J - 1)^2, ArtiSynth's default ``BulkPotential`` QUADRATIC. Under a uniform
dilatation the mesh's energy and the pressure are each potential's closed form; the two agree to
second order in J - 1; a model with the quadratic one saves as format 6 and loads with it."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from wface.model import FORMAT_VERSION, Material, ModelError, load_model, save_model
from wface.physics import Simulator
from wface.testing.models import box_model

_KAPPA = 25000.0  # Pa, ArtiSynth's Badin flesh (10 C10)
_BULK_ONLY = {p: Material(mu10_pa=0.0, mu01_pa=0.0, kappa_pa=_KAPPA, bulk_potential=p) for p in ("log", "quadratic")}


def _dilated(model, lam: float) -> np.ndarray:
    """x = c + lam (X - c): a uniform dilatation about the centroid, J = lam^3."""
    X = model.rest_positions_m
    c = X.mean(axis=0)
    return c + lam * (X - c)


@pytest.mark.parametrize("potential", ["log", "quadratic"])
def test_uniform_dilatation_energy_and_pressure_are_the_closed_form(potential):
    """E = V0 U(J); the virtual work of the nodal forces on the dilatation's rate dx/dlam = X - c is
    -dE/dlam = -V0 U'(J) 3 lam^2, i.e. the pressure U'(J) = kappa (J - 1) or kappa ln J / J times dV/dlam."""
    model = box_model((2, 2, 2), muscles=0).with_material(_BULK_ONLY[potential])
    sim = Simulator(model, precision="float64")
    V0 = float(model.rest_volume_m3.sum())
    X = model.rest_positions_m
    for lam in (0.9, 0.97, 1.05, 1.2):
        J = lam**3
        U, dU = (
            (0.5 * _KAPPA * (J - 1) ** 2, _KAPPA * (J - 1))
            if potential == "quadratic"
            else (0.5 * _KAPPA * np.log(J) ** 2, _KAPPA * np.log(J) / J)
        )
        energy, forces = sim.energy_and_forces(_dilated(model, lam), np.zeros(0))
        assert energy == pytest.approx(V0 * U, rel=1e-12)
        work = float(np.sum(forces * (X - X.mean(axis=0))))
        assert work == pytest.approx(-V0 * dU * 3 * lam**2, rel=1e-10)


def test_the_two_potentials_agree_to_second_order_and_part_beyond():
    """Same energy to O((J - 1)^3) (both kappa/2 (J - 1)^2 at leading order); at J = 0.8 the log
    potential's pressure kappa ln J / J is 39 % above the quadratic's kappa (J - 1) in magnitude."""
    model = box_model((2, 2, 2), muscles=0)
    energies = {}
    for p, mat in _BULK_ONLY.items():
        sim = Simulator(model.with_material(mat), precision="float64")
        energies[p] = [sim.energy_and_forces(_dilated(model, lam), np.zeros(0))[0] for lam in (1.001, 0.8 ** (1 / 3))]
    assert energies["log"][0] == pytest.approx(energies["quadratic"][0], rel=5e-3)  # J - 1 = 3e-3
    assert energies["log"][1] / energies["quadratic"][1] == pytest.approx(np.log(0.8) ** 2 / 0.04, rel=1e-10)
    assert (np.log(0.8) / 0.8) / -0.2 == pytest.approx(1.395, abs=1e-3)


def test_model_with_the_quadratic_potential_saves_as_format_6_and_loads_with_it(tmp_path):
    quad = replace(Material.artisynth(), bulk_potential="quadratic")
    path = save_model(box_model((2, 1, 1), muscles=0).with_material(quad), tmp_path / "quad.npz")
    header = json.loads(bytes(np.load(path)["header_json"]).decode())
    assert header["format_version"] == 6 <= FORMAT_VERSION and header["material"]["bulk_potential"] == "quadratic"
    assert load_model(path).material == quad
    plain = save_model(box_model((2, 1, 1), muscles=0), tmp_path / "plain.npz")
    assert "bulk_potential" not in json.loads(bytes(np.load(plain)["header_json"]).decode())["material"]
    assert load_model(plain).material.bulk_potential == "log"


def test_an_unknown_potential_is_refused_by_name():
    with pytest.raises(ModelError, match=r"bulk_potential must be one of \('log', 'quadratic'\), got 'cubic'"):
        Material(bulk_potential="cubic")


def test_model_info_prints_the_bulk_potential(tmp_path, capsys):
    from wface.cli import main

    quad = replace(Material.artisynth(), bulk_potential="quadratic")
    path = save_model(box_model((2, 1, 1), muscles=0).with_material(quad), tmp_path / "quad.npz")
    assert main(["model", "info", str(path)]) == 0
    assert "kappa 25000 Pa (quadratic bulk potential)" in capsys.readouterr().out
