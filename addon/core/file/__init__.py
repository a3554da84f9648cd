"""The file step: where a material comes from, and every read and write that must not lose
anything (SPEC §2, §7). Modules in the order a run uses them:

- ``sources``: ``FILE:NAME`` sources told apart from MERL files by the path alone.
- ``names``: material and output names that cannot leave the folder they are meant for.
- ``safeio``: the one guard for every output and the one opener for every input (size first,
  regular files only, EXR/HDR headers, bounded JSON).
- ``atomic``: atomic writes behind that guard, and the journal of temporaries.
- ``cachefs``: cache entries sealed by size and CRC-32, and bounded cache folders.
- ``exr``: float OpenEXR images written without Blender (textures made in a job's work).
- ``merl``: the MERL table: read, validate, write, look up, tabulate an analytic BRDF.
- ``nbrdf``: Neural-BRDF networks decoded into MERL tables.
"""

from .merl import MerlError, MerlTable, lookup, read_merl, tabulate, write_merl
from .names import material_name, safe_name
from .nbrdf import WeightsError, list_materials, load_network, read_table
from .safeio import UnsafePath
from .sources import parse_source

__all__ = [
    "MerlError",
    "MerlTable",
    "UnsafePath",
    "WeightsError",
    "list_materials",
    "load_network",
    "lookup",
    "material_name",
    "parse_source",
    "read_merl",
    "read_table",
    "safe_name",
    "tabulate",
    "write_merl",
]
