"""pyarrow schemas and the support geometry, from the generated contract in schema.json."""

import json
from pathlib import Path

import pyarrow as pa

_CONTRACT = json.loads((Path(__file__).parent / "schema.json").read_text())

SCHEMA_VERSION: int = _CONTRACT["schema_version"]
VERSION_KEY: str = _CONTRACT["version_key"]
TABLE_KEY: str = _CONTRACT["table_key"]
TABLES: dict[str, dict] = {t["name"]: t for t in _CONTRACT["tables"]}

# The support geometries the `scenes.support` values name (rust/data/src/support.rs): every
# stage builds its floor, bin or pallet from these.
SUPPORT: dict[str, float] = _CONTRACT["support"]
# Height of the pallet deck's top above the ground (m).
PALLET_HEIGHT_M: float = SUPPORT["pallet_height_m"]
# Thickness of a bin's walls, outside the support region (m).
BIN_WALL_THICKNESS_M: float = SUPPORT["bin_wall_thickness_m"]
# Coulomb friction of every support surface (ground, bin walls, pallet).
SUPPORT_FRICTION: float = SUPPORT["friction"]

# What a scene recipe may hold (rust/data/src/recipe.rs): its keys, dotted by section; the
# support kinds; the values of materials.tape_along, settle.engine and camera.region and the ones
# a recipe without them means; the most simulation steps one settle may take.
RECIPE_KEYS: frozenset[str] = frozenset(_CONTRACT["recipe"]["keys"])
# Each key's type, accepted values, default and meaning, by dotted key (boxpose_io.recipe checks
# a recipe against it).
RECIPE_REFERENCE: dict[str, dict] = {k["key"]: k for k in _CONTRACT["recipe"]["reference"]}
SUPPORT_KINDS: tuple[str, ...] = tuple(_CONTRACT["recipe"]["support_kinds"])
TAPE_ALONG: tuple[str, ...] = tuple(_CONTRACT["recipe"]["tape_along"])
TAPE_ALONG_DEFAULT: str = _CONTRACT["recipe"]["tape_along_default"]
SETTLE_ENGINES: tuple[str, ...] = tuple(_CONTRACT["recipe"]["settle_engines"])
SETTLE_ENGINE_DEFAULT: str = _CONTRACT["recipe"]["settle_engine_default"]
CAMERA_REGIONS: tuple[str, ...] = tuple(_CONTRACT["recipe"]["camera_regions"])
CAMERA_REGION_DEFAULT: str = _CONTRACT["recipe"]["camera_region_default"]
MAX_SETTLE_STEPS: float = _CONTRACT["recipe"]["max_settle_steps"]


def _arrow_type(column: dict) -> pa.DataType:
    scalar = getattr(pa, column["type"])()
    if column["list_size"] is None:
        return scalar
    # A plain list (Parquet has no fixed-size list); its length is checked by table_from_rows.
    return pa.list_(pa.field("item", scalar, nullable=True))


def arrow_schema(table: str) -> pa.Schema:
    """The pyarrow schema of `table`, with the schema version and table name in its metadata."""
    spec = TABLES[table]
    fields = [pa.field(c["name"], _arrow_type(c), nullable=c["nullable"]) for c in spec["columns"]]
    return pa.schema(fields, metadata={VERSION_KEY: str(SCHEMA_VERSION), TABLE_KEY: table})


def column_names(table: str) -> list[str]:
    return [c["name"] for c in TABLES[table]["columns"]]
