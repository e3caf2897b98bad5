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

__all__ = ["NOTES", "TOTAL_V2_CLASSES", "TOTALSEGMENTATOR", "tissue_for", "markdown_table"]


def _total_v2() -> dict[int, str]:
    """Label number -> class name of TotalSegmentator's ``total`` task, v2 (its ``class_map["total"]``)."""
    names = ["spleen", "kidney_right", "kidney_left", "gallbladder", "liver", "stomach", "pancreas",
             "adrenal_gland_right", "adrenal_gland_left", "lung_upper_lobe_left", "lung_lower_lobe_left",
             "lung_upper_lobe_right", "lung_middle_lobe_right", "lung_lower_lobe_right", "esophagus", "trachea",
             "thyroid_gland", "small_bowel", "duodenum", "colon", "urinary_bladder", "prostate", "kidney_cyst_left",
             "kidney_cyst_right", "sacrum", "vertebrae_S1"]
    names += [f"vertebrae_L{i}" for i in range(5, 0, -1)] + [f"vertebrae_T{i}" for i in range(12, 0, -1)]
    names += [f"vertebrae_C{i}" for i in range(7, 0, -1)]
    names += ["heart", "aorta", "pulmonary_vein", "brachiocephalic_trunk", "subclavian_artery_right",
              "subclavian_artery_left", "common_carotid_artery_right", "common_carotid_artery_left",
              "brachiocephalic_vein_left", "brachiocephalic_vein_right", "atrial_appendage_left", "superior_vena_cava",
              "inferior_vena_cava", "portal_vein_and_splenic_vein", "iliac_artery_left", "iliac_artery_right",
              "iliac_vena_left", "iliac_vena_right", "humerus_left", "humerus_right", "scapula_left", "scapula_right",
              "clavicula_left", "clavicula_right", "femur_left", "femur_right", "hip_left", "hip_right", "spinal_cord",
              "gluteus_maximus_left", "gluteus_maximus_right", "gluteus_medius_left", "gluteus_medius_right",
              "gluteus_minimus_left", "gluteus_minimus_right", "autochthon_left", "autochthon_right", "iliopsoas_left",
              "iliopsoas_right", "brain", "skull"]
    names += [f"rib_left_{i}" for i in range(1, 13)] + [f"rib_right_{i}" for i in range(1, 13)]
    names += ["sternum", "costal_cartilages"]
    return {i + 1: n for i, n in enumerate(names)}


#: TotalSegmentator's ``total`` task (v2): label number -> class name. A manifest without ``labels`` reads
#: its volume's label numbers this way (e.g. label 5 is the liver).
TOTAL_V2_CLASSES: dict[int, str] = _total_v2()

_BONES = ("vertebrae_", "rib_", "sacrum", "hip_", "femur_", "humerus_", "scapula_", "clavicula_", "sternum",
          "skull")
_VESSELS = ("heart_atrium_", "heart_ventricle_", "aorta", "inferior_vena_cava", "superior_vena_cava",
            "portal_vein_and_splenic_vein", "iliac_artery_", "iliac_vena_", "pulmonary_vein", "brachiocephalic_trunk",
            "brachiocephalic_vein_", "common_carotid_artery_", "subclavian_artery_", "atrial_appendage_left",
            "pulmonary_artery")
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
    "heart_myocardium": "heart",
    "intervertebral_discs": "cartilage",
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
