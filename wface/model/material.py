"""The face model's material: flesh and muscle laws (docs/design.md, "Flesh", "Muscle fibres"), and
``ModelError``, the error every part of a face model raises."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ["BULK_POTENTIALS", "FIBRE_CURVES", "FIBRE_STRESSES", "Material", "ModelError"]

FIBRE_STRESSES = ("uniaxial", "deviatoric", "blemker")  # Material.fibre_stress; the first is the default
FIBRE_CURVES = ("wface", "blemker", "generic")  # a muscle's f_L and f_P (Material.muscle_curves); kernel index
BULK_POTENTIALS = ("log", "quadratic")  # Material.bulk_potential: kappa/2 (ln J)^2 (default) or kappa/2 (J - 1)^2


class ModelError(ValueError):
    """A face model is inconsistent; the message names the problem and where it is."""


@dataclass(frozen=True)
class Material:
    """Flesh and muscle material (Teran et al. 2005; docs/design.md, "Flesh").

    Flesh: Psi = mu10 (I1~ - 3) + mu01 (I2~ - 3) + mu20 (I1~ - 3)^2 + U(J), with
    I1~ = J^-2/3 I1 and I2~ = J^-4/3 I2 (all moduli in Pa; mu20 is ArtiSynth's C20, default 0) and the
    bulk potential U = kappa/2 (ln J)^2 (``bulk_potential = "log"``, the default) or kappa/2 (J - 1)^2
    ("quadratic", ArtiSynth's default ``BulkPotential``).
    Muscle: fibre tension T = sigma_max (a f_L(lam) + f_P(lam)), times the tet's volume fraction,
    of the fibre stretch lam = |F d| (``fibre_stress = "uniaxial"``: Cauchy stress T/J (F d)(F d)^T/lam,
    hydrostatic part T/(3J)) or of the deviatoric stretch lam~ = J^-1/3 |F d| (``"deviatoric"``, as
    ArtiSynth's muscle materials: no hydrostatic part), "blemker" that with BlemkerMuscle's curves (docs/design.md).
    ``muscle_curves``: (muscle, one of ``FIBRE_CURVES``) pairs giving those muscles their own curves ("generic":
    ArtiSynth's GenericMuscle, f_L = 1, no passive stress); a dict is taken. Checked on construction (``validate``).
    """

    mu10_pa: float = 6.0e4
    mu01_pa: float = 2.0e4
    kappa_pa: float = 3.0e6
    sigma_max_pa: float = 3.0e5
    inversion_clamp: float = 0.1  # singular values are clamped below at this value (Irving et al. 2004)
    density_kg_m3: float = 1040.0
    mu20_pa: float = 0.0  # coefficient of (I1~ - 3)^2; last so positional use of the others is unchanged
    fibre_stress: str = "uniaxial"  # "deviatoric", "blemker": fibre curves of J^-1/3 |F d| (FIBRE_STRESSES)
    muscle_curves: tuple[tuple[str, str], ...] = ()  # (muscle, FIBRE_CURVES entry), sorted by muscle
    bulk_potential: str = "log"  # U(J): "log" kappa/2 (ln J)^2 or "quadratic" kappa/2 (J - 1)^2 (BULK_POTENTIALS)

    def __post_init__(self) -> None:
        pairs = self.muscle_curves.items() if isinstance(self.muscle_curves, dict) else self.muscle_curves
        object.__setattr__(self, "muscle_curves", tuple(sorted((str(m), str(c)) for m, c in pairs)))
        self.validate()

    def validate(self) -> None:
        """Raise ``ModelError`` naming the field: every value must be finite, mu20_pa >= 0 (the
        (I1~ - 3)^2 term is then convex in I1~, so it can only stiffen the flesh) and fibre_stress one
        of ``FIBRE_STRESSES``, bulk_potential one of ``BULK_POTENTIALS``, each muscle's curves one of
        ``FIBRE_CURVES``, named once."""
        if self.bulk_potential not in BULK_POTENTIALS:
            raise ModelError(f"material: bulk_potential must be one of {BULK_POTENTIALS}, got {self.bulk_potential!r}")
        if self.fibre_stress not in FIBRE_STRESSES:
            raise ModelError(f"material: fibre_stress must be one of {FIBRE_STRESSES}, got {self.fibre_stress!r}")
        for muscle, curves in self.muscle_curves:
            if curves not in FIBRE_CURVES:
                raise ModelError(f"material: muscle {muscle!r}: curves must be one of {FIBRE_CURVES}, got {curves!r}")
        if len({m for m, _ in self.muscle_curves}) < len(self.muscle_curves):
            raise ModelError(f"material: a muscle is named twice in muscle_curves {self.muscle_curves}")
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name not in ("fibre_stress", "muscle_curves", "bulk_potential") and not np.isfinite(value):
                raise ModelError(f"material: {f.name} must be finite, got {value!r}")
        if self.mu20_pa < 0:
            raise ModelError(f"material: mu20_pa must be >= 0 (coefficient of (I1~ - 3)^2), got {self.mu20_pa!r}")

    @classmethod
    def artisynth(cls) -> Material:
        """ArtiSynth's Badin face flesh (``BadinFaceDemo.setFaceProperties``, Nazari et al. 2010):
        MooneyRivlinMaterial C10 = 2500 Pa, C20 = 1175 Pa, bulk modulus 10 C10 = 25 kPa. ArtiSynth's
        bulk potential is kappa/2 (J - 1)^2, wface's kappa/2 (ln J)^2 (docs/design.md, "Flesh")."""
        return cls(mu10_pa=2500.0, mu01_pa=0.0, mu20_pa=1175.0, kappa_pa=25000.0)

    def bulk_moduli_pa(self) -> tuple[float, float]:
        """(kappa of (ln J)^2, kappa of (J - 1)^2): the flesh kernels' two bulk moduli, one of them 0."""
        return (self.kappa_pa, 0.0) if self.bulk_potential == "log" else (0.0, self.kappa_pa)

    def curves_of(self, muscle_names: list[str]) -> np.ndarray:
        """(M,) int32 index into ``FIBRE_CURVES`` of each muscle's curves: its own, else the law's."""
        own = dict(self.muscle_curves)
        law = "blemker" if self.fibre_stress == "blemker" else "wface"
        return np.array([FIBRE_CURVES.index(own.get(m, law)) for m in muscle_names], dtype=np.int32)
