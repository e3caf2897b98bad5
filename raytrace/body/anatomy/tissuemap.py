"""TotalSegmentator class names -> Gabriel 1996 tissues (docs/phantoms.md, "The tissue map").

An organ taken from a labelled volume without a ``tissue`` gets the tissue its label's class name
maps to here; a class name that is not here (or a label without a name) needs an explicit tissue,
and the build says so naming the organ and the label. Class names are those of TotalSegmentator's
``total`` task (v2) and of its ``tissue_types`` and ``body`` tasks (Wasserthal et al., Radiology:
AI 5, e230024, 2023). Where the Gabriel table has no tissue of that name the nearest tissue it has is
used and the reason is given (``NOTES``); segmented vessels are their lumen, so blood.
"""

from __future__ import annotations

import re

__all__ = ["NOTES", "TOTALSEGMENTATOR", "tissue_for", "markdown_table"]

_BONES = ("vertebrae_", "rib_", "sacrum", "hip_", "femur_", "humerus_", "scapula_", "clavicula_", "sternum",
          "skull")
_VESSELS = ("aorta", "inferior_vena_cava", "superior_vena_cava", "portal_vein_and_splenic_vein", "iliac_artery_",
            "iliac_vena_", "pulmonary_vein", "brachiocephalic_trunk", "brachiocephalic_vein_", "common_carotid_artery_",
            "subclavian_artery_", "atrial_appendage_left", "pulmonary_artery")
_MUSCLES = ("gluteus_", "iliopsoas_", "autochthon_", "skeletal_muscle")

#: Exact class names and the tissue they map to.
TOTALSEGMENTATOR: dict[str, str] = {
    "spleen": "spleen",
    "kidney_right": "kidney",
    "kidney_left": "kidney",
    "gallbladder": "gall_bladder",
    "liver": "liver",
    "stomach": "stomach",
    "esophagus": "stomach",
    "small_bowel": "small_intestine",
    "duodenum": "small_intestine",
    "colon": "colon",
    "urinary_bladder": "bladder",
    "heart": "heart",
    "spinal_cord": "nerve",
    "costal_cartilages": "cartilage",
    "lung_upper_lobe_left": "lung_inflated",
    "lung_lower_lobe_left": "lung_inflated",
    "lung_upper_lobe_right": "lung_inflated",
    "lung_middle_lobe_right": "lung_inflated",
    "lung_lower_lobe_right": "lung_inflated",
    "subcutaneous_fat": "fat_average_infiltrated",
    "torso_fat": "fat_average_infiltrated",
}

#: Prefix rules, in order: a class name starting with the prefix maps to the tissue.
_PREFIXES: tuple[tuple[tuple[str, ...], str], ...] = (
    (_BONES, "bone_cortical"),
    (_VESSELS, "blood"),
    (_MUSCLES, "muscle"),
)

#: Why a class maps to a tissue of another name.
NOTES = {
    "esophagus": "no oesophagus in the Gabriel table: the GI wall of the stomach",
    "bones": "vertebrae, ribs, sacrum, hip, femur, humerus, scapula, clavicle, sternum, skull: cortical bone, as "
             "the default torso's spine",
    "vessels": "segmented vessels and heart chambers' appendages are their lumen: blood",
    "muscles": "gluteus, iliopsoas, autochthon and skeletal muscle: muscle",
    "lungs": "lung lobes: inflated lung",
}

_NAME = re.compile(r"^[a-z0-9_]+$")


def tissue_for(class_name: str) -> str | None:
    """The tissue of a TotalSegmentator class name, or None when it has none here."""
    name = class_name.strip().lower()
    if not _NAME.match(name):
        return None
    if name in TOTALSEGMENTATOR:
        return TOTALSEGMENTATOR[name]
    for prefixes, tissue in _PREFIXES:
        if name.startswith(prefixes):
            return tissue
    return None


def markdown_table() -> str:
    """The map as the Markdown table of docs/phantoms.md (a test keeps the two equal)."""
    rows = ["| TotalSegmentator class | tissue |", "|---|---|"]
    rows += [f"| `{name}` | `{tissue}` |" for name, tissue in TOTALSEGMENTATOR.items()]
    for prefixes, tissue in _PREFIXES:
        rows.append(f"| {', '.join(f'`{p}*`' if p.endswith('_') else f'`{p}`' for p in prefixes)} | `{tissue}` |")
    return "\n".join(rows)
