"""The anatomy pipeline: phantoms from surface meshes and labelled volumes (docs/phantoms.md).

``build_phantom(manifest, root)`` (:mod:`raytrace.body.anatomy.build`) is the one entry point; the
modules beside it each do one job: the manifest, the file readers, repairs, labelled volumes, decimation,
overlaps, the body wall, tracts, sensors and the tissue map.
"""

from raytrace.body.anatomy.build import BuildResult, Limits, build_phantom, check_limits, markdown_report
from raytrace.body.anatomy.manifest import load_manifest, parse_manifest_text

__all__ = ["BuildResult", "Limits", "build_phantom", "check_limits", "load_manifest", "markdown_report",
           "parse_manifest_text"]
