"""Where the forest species' foliage comes from: each figure with its source, and what is ours.

The random-tree presets (:data:`~simlidar_mi.plants.tree_params.SPECIES_PRESETS`) take their
leaf (or shoot) size from the figures below, and their leaf count per leaf-bearing segment is
chosen (ours) so that a tree's **crown LAI** — its one-sided leaf area over its crown's
projection (the convex hull of its leaves and branches seen from above) — lies in the
published range of the species' closed stands. A leaf-bearing segment of the generator stands
for the twigs and shoots it does not grow, so its leaf count (tens to hundreds) is leaves per
shoot × shoots per segment; that product is ours, fitted to the range, and said so.

Conifer foliage (``conifer-whorl``) is modelled as the literature models it: a shoot is one
flat element, and its one-sided area is what the sensors see; the needle area it stands for
follows from the shoot silhouette to total needle area ratio STAR (Oker-Blom & Smolander 1988;
Stenberg et al.). A flat element of one-sided area ``A`` has a mean silhouette ``A/2`` over
all directions, so its total needle area is ``A / (2·STAR)`` and its needle LAI contribution
(half the total needle area, Chen & Black 1992) is ``A / (4·STAR)``
(:func:`needle_area_factor`). The truth tables score the element area (what the sensor
sees); ``forest`` also reports the needle area.

Every figure is a :class:`Cited` value: ``checked=False`` marks one recalled from its
source (or taken from the issue's brief) but not read in it here.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["Cited", "SpeciesFoliage", "SOURCES", "SPECIES_FOLIAGE", "needle_area_factor"]

UNCHECKED = "recalled, not checked against the source"


@dataclass(frozen=True)
class Cited:
    """One figure, the id of the document it comes from (:data:`SOURCES`) and how it was read."""

    value: Any
    source: str
    note: str = ""
    checked: bool = True

    def to_dict(self) -> dict:
        return {"value": self.value, "source": SOURCES.get(self.source, self.source),
                "note": self.note, "checked": self.checked}


SOURCES: dict[str, str] = {
    "leuschner2006": "Leuschner, Voß, Foetzki, Clases (2006) Variation in leaf area index and stand "
                     "leaf mass of European beech across gradients of soil acidity and precipitation. "
                     "Plant Ecology 182: 247–258 (litter traps, 23 stands)",
    "cerny2020": "Černý, Haninec, Pokorný (2020) Leaf area index estimated by direct, semi-direct and "
                 "indirect methods in European beech and sycamore maple stands. J. For. Res. 31: 827–836",
    "bartelink1997": "Bartelink (1997) Allometric relationships for biomass and leaf area of beech "
                     "(Fagus sylvatica L). Ann. Sci. For. 54: 39–50",
    "beech_leaf": "Fagus sylvatica, species description (Wikipedia 'Fagus sylvatica', as reproduced "
                  "by plantsnap.com): leaves 5–10 cm long, 3–7 cm broad",
    "elm_leaf": "Dutch elm (Ulmus × hollandica), Amsterdam street trees in three vitality classes: "
                "leaf area 29.5 ± 3.2, 38.1 ± 11.6, 37.9 ± 5.4 cm² per leaf (J. Arboriculture, "
                "Table 1, 1986 sampling; auf.isa-arbor.com)",
    "hawthorn_leaf": "Crataegus monogyna: leaves 2–4 cm long (Wikipedia 'Common hawthorn'); blades "
                     "4–7 × 2–6 cm (KPU Plant Database); length 2–6 cm (Wageningen tree factsheet)",
    "asner2003": "Asner, Scurlock, Hicke (2003) Global synthesis of leaf area index observations. "
                 "Global Ecol. Biogeogr. 12: 191–205: mean (± SD) LAI 4.5 ± 2.5 over all biomes "
                 "after outlier removal; temperate evergreen forests 5.1–6.7",
    "burger1953": "Burger (1953), as cited for Norway spruce (ecologycenter.us 'Norway spruce: "
                  "needles'): a 152-year-old tree with 25 million needles, 1,410 m² total needle "
                  "surface, 290 kg; needles 25–35 mm long, about 1 mm wide; stand LAI 10.5 (Bolstad & "
                  "Gower 1990)",
    "okerblom1988": "Oker-Blom, Smolander (1988) The ratio of shoot silhouette area to total needle "
                    "area in Scots pine. For. Sci. 34: 894–906: mean STAR 0.09–0.21, average 0.14",
    "stenberg1995": "Stenberg, Linder, Smolander (1995) Variation in the ratio of shoot silhouette "
                    "area to needle area in fertilized and unfertilized Norway spruce trees. Tree "
                    "Physiol. 15: 705–712 (STAR falls with canopy openness)",
    "chen1992": "Chen, Black (1992) Defining leaf area index for non-flat leaves. Plant Cell "
                "Environ. 15: 421–429: LAI = half the total needle area per unit ground area",
    "kuusinen2021": "Kuusinen, Hovi, Rautiainen (2021) Contribution of woody elements to tree level "
                    "reflectance in boreal forests. Silva Fennica 55(5) 10600: 0.09–0.10 (Norway "
                    "spruce), 0.12–0.20 (birches)",
    "ours": "this project's choice",
}


@dataclass(frozen=True)
class SpeciesFoliage:
    """The cited foliage of one random-tree preset.

    ``leaf_area_cm2``: one leaf's (or shoot element's) one-sided area, (lo, hi);
    ``crown_lai``: the range a tree's crown LAI is to lie in, (lo, hi);
    ``star``: a conifer's shoot STAR (None for broadleaves); ``figures``: every other figure
    the preset's values rest on; ``ours``: which of the preset's values are this project's.
    """

    species: str
    leaf_area_cm2: Cited
    crown_lai: Cited
    star: Cited | None = None
    figures: dict[str, Cited] = field(default_factory=dict)
    ours: str = ""

    def to_dict(self) -> dict:
        out = {"species": self.species, "leaf_area_cm2": self.leaf_area_cm2.to_dict(),
               "crown_lai": self.crown_lai.to_dict(), "ours": self.ours,
               "figures": {k: v.to_dict() for k, v in self.figures.items()}}
        if self.star is not None:
            out["star"] = self.star.to_dict()
        return out


def needle_area_factor(star: float) -> float:
    """Half-total needle area per unit one-sided area of a flat shoot element: ``1 / (4·STAR)``.

    A flat element of one-sided area ``A`` has mean silhouette ``A/2`` over all directions;
    STAR = mean silhouette / total needle area gives total needle area ``A/(2·STAR)``, and LAI
    as half the total needle area (Chen & Black 1992) ``A/(4·STAR)``. ``star = 0``: the
    elements are leaves (factor 1).

    >>> needle_area_factor(0.16)
    1.5625
    >>> needle_area_factor(0.0)
    1.0
    """
    return 1.0 if star == 0 else 1.0 / (4.0 * star)


_C = Cited
SPECIES_FOLIAGE: dict[str, SpeciesFoliage] = {
    "deciduous-apex": SpeciesFoliage(
        "elm (Ulmus)",
        leaf_area_cm2=_C((29.5, 38.1), "elm_leaf", "class means of Dutch elm street trees; the "
                         "preset's rhombus leaf ½·ℓ·0.55ℓ with ℓ ≈ 11 cm gives ≈ 33 cm²"),
        crown_lai=_C((2.0, 8.0), "asner2003", "no elm-stand figure found: the all-biome mean ± SD "
                     "(4.5 ± 2.5, from 2.0) up to the beech-stand range's 8 (leuschner2006)"),
        figures={"wood_share": _C((0.12, 0.20), "kuusinen2021", "broadleaf (birch) woody share of "
                                  "reflectance; the preset's wood is grown, its share measured")},
        ours="leaves per leaf-bearing segment (260–320, for the crown LAI), growth levels 7–8 "
             "(one more generation of twigs than before), leaf width ratio 0.55, the architecture"),
    "conifer-whorl": SpeciesFoliage(
        "Norway spruce (Picea abies)",
        leaf_area_cm2=_C((12.0, 28.0), "ours", "a shoot as one flat rhombus element, 8 cm long "
                         "(ours) and as wide as its needle cylinder, ≈ 2 × 25–35 mm needles at "
                         "~55° (burger1953): width ratio 0.6"),
        crown_lai=_C((3.0, 10.5), "asner2003", "needle LAI (half the total needle area, "
                     "chen1992): from 3 up to the 10.5 of a spruce stand (burger1953, Bolstad & "
                     "Gower 1990); temperate evergreen forests average 5.1–6.7"),
        star=_C(0.16, "stenberg1995", "Norway spruce shoots 0.14–0.18 (value from the issue's "
                "brief, Stenberg et al.; the Scots pine range 0.09–0.21 of okerblom1988 is "
                "checked)", checked=False),
        figures={"needle_total_area_cm2": _C(1410e4 / 25e6, "burger1953",
                                             "1,410 m² / 25 million needles = 0.56 cm² a needle "
                                             "(all sides): a 19 cm² element stands for 61 cm² of "
                                             "needles, ≈ 110 needles on its 8 cm (14 a cm)"),
                 "lai_definition": _C("half total needle area", "chen1992"),
                 "wood_share": _C((0.09, 0.10), "kuusinen2021", "Norway spruce")},
        ours="shoot length 8 cm, shoots per leaf-bearing segment (84–108, for the crown LAI), "
             "the architecture"),
    "broadleaf-monopodial": SpeciesFoliage(
        "European beech (Fagus sylvatica)",
        leaf_area_cm2=_C((12.5, 35.0), "beech_leaf", "5–10 cm × 3–7 cm blades; the preset's "
                         "rhombus ½·ℓ·0.65ℓ with ℓ ≈ 8 cm gives ≈ 21 cm²"),
        crown_lai=_C((4.5, 9.5), "leuschner2006", "closed stands 7.4 (5.6–9.5) by litter traps; "
                     "4.5–5.1 at the seasonal maximum in Czech stands (cerny2020)"),
        figures={"sla_cm2_per_g": _C(172.0, "bartelink1997", "whole-tree mean specific leaf area: "
                                     "250 m² of leaves ≈ 14.5 kg dry leaf mass")},
        ours="leaves per leaf-bearing segment (160–200, for the crown LAI), growth levels 9–11, "
             "the architecture"),
    "small-tree": SpeciesFoliage(
        "hawthorn (Crataegus monogyna)",
        leaf_area_cm2=_C((3.0, 20.0), "hawthorn_leaf", "2–6 cm long blades; the preset's rhombus "
                         "½·ℓ·0.8ℓ with ℓ ≈ 4 cm gives ≈ 6.5 cm²"),
        crown_lai=_C((2.0, 7.0), "asner2003", "no hawthorn-scrub figure found: the all-biome mean "
                     "± SD 4.5 ± 2.5; the preset sits low in it (a shrub)"),
        ours="leaves per leaf-bearing segment (300–360, for the crown LAI), rhombus leaves (2 "
             "triangles; the earlier hexagon had 6), the architecture"),
}
