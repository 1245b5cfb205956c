"""Objects: the catalog (`catalog/objects.toml`), shapes parsed from it or from task parameters,
and the models engines build from them — a watertight mesh in the object frame, convex pieces for
collision, mass properties, a resting pose and the model PLY (millimetres) the dataset ships.

Plain typed functions over plain data; no engine state lives here (engines hold an `ObjectModels`
cache). Must not import MuJoCo or Blender: both the grasp and the render engine use it.
"""

from vint_engines.objects.catalog import CATALOG_DIR, OBJECTS_TOML, load_catalog
from vint_engines.objects.decompose import ConvexPiece
from vint_engines.objects.model import MODEL_FILE, MODEL_MEDIA_TYPE, ObjectModel, ObjectModels, build_model
from vint_engines.objects.rest import RestPose
from vint_engines.objects.spec import MATERIALS, Colours, ObjectSpec, Symmetries, Texture

__all__ = [
    "CATALOG_DIR",
    "MATERIALS",
    "MODEL_FILE",
    "MODEL_MEDIA_TYPE",
    "OBJECTS_TOML",
    "Colours",
    "ConvexPiece",
    "ObjectModel",
    "ObjectModels",
    "ObjectSpec",
    "RestPose",
    "Symmetries",
    "Texture",
    "build_model",
    "load_catalog",
]
