"""The six parametrizations of the paper (DESIGN §3) as one explicit type.

A variant is which features the window optimizes (points, or points and lines) and how it
uses planes: `wo` without them, `r` with feature-to-plane residuals, `w` with the features
on a plane parametrized by it. `Variant` is a string enum, so a variant prints, compares
and serializes as its name ("PL-w") while code asks it what it means instead of parsing
the name. Names are parsed once, where they enter (`Variant.parse`).

A seventh variant is one member here (its name, `with_lines` and `plane_mode` follow from
the name's two parts) plus what `backend.optim.problem.build_problem` does for a new
plane mode.
"""

from __future__ import annotations

import enum


class PlaneMode(enum.StrEnum):
    """How the window uses planes: not at all, as residuals, or as the features' parameters."""

    WITHOUT = "wo"
    RESIDUAL = "r"
    PARAMETRIZED = "w"


class Variant(enum.StrEnum):
    """A parametrization, named as in the paper: P (points) or PL (points and lines), then
    the plane mode."""

    P_WO = "P-wo"
    P_R = "P-r"
    P_W = "P-w"
    PL_WO = "PL-wo"
    PL_R = "PL-r"
    PL_W = "PL-w"

    @classmethod
    def parse(cls, name: str) -> Variant:
        """The variant named `name`; ValueError (naming the variants) for any other."""
        try:
            return cls(name)
        except ValueError:
            raise ValueError(f"unknown variant {name!r}; expected one of {', '.join(VARIANTS)}") from None

    @property
    def with_lines(self) -> bool:
        """Whether lines are optimized besides points."""
        return self.value.split("-")[0] == "PL"

    @property
    def plane_mode(self) -> PlaneMode:
        return PlaneMode(self.value.split("-")[1])

    @property
    def uses_planes(self) -> bool:
        """Whether the optimizer uses planes at all (-r and -w)."""
        return self.plane_mode is not PlaneMode.WITHOUT

    def family(self) -> tuple[Variant, ...]:
        """The variants with this one's features, one per plane mode (-wo, -r, -w)."""
        return tuple(v for v in Variant if v.with_lines == self.with_lines)


VARIANTS: tuple[Variant, ...] = tuple(Variant)
VARIANT_NAMES: tuple[str, ...] = tuple(v.value for v in Variant)  # as text, for option choices and GUI menus
