"""Scene settings (``Scene.facecap``): everything a re-solve needs is saved in the .blend."""

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

STRATEGY_ITEMS = [
    ("geometric", "Geometric", "Solve marker deltas against the character's shape keys at the bound vertices"),
]
UNIT_ITEMS = [
    ("mm", "Millimetres", "Marker coordinates are in millimetres"),
    ("cm", "Centimetres", "Marker coordinates are in centimetres"),
    ("m", "Metres", "Marker coordinates are in metres"),
]


def _is_face_mesh(_self, obj):
    return obj.type == "MESH" and obj.data.shape_keys is not None


class FACECAP_PG_marker(bpy.types.PropertyGroup):
    """One imported marker; ``name`` is the marker name."""

    stable: BoolProperty(
        name="Stable",
        description="Moves only with the head (forehead, temples, nose bridge): used to remove head motion",
        default=False,
    )
    gaps: IntProperty(name="Gaps", description="Missing samples in the take", default=0)


class FACECAP_PG_shape(bpy.types.PropertyGroup):
    """Solve options of one shape key; ``name`` is the shape key's name."""

    lock: BoolProperty(name="Lock", description="Hold this shape at the lock value in the solve (animator-owned)")
    lock_value: FloatProperty(name="Value", default=0.0, description="Value a locked shape is held at")
    lower: FloatProperty(name="Min", default=0.0, description="Lower bound of the solved weight")
    upper: FloatProperty(name="Max", default=1.0, description="Upper bound of the solved weight")
    region: StringProperty(name="Region", description="Region solving this shape (empty: the whole face)")


class FACECAP_PG_region(bpy.types.PropertyGroup):
    """A face region: its shapes are solved only from its markers; ``name`` is the region's name."""

    markers: StringProperty(
        name="Markers", description="Comma-separated marker name patterns, e.g. brow*, eye*, forehead*, head_*"
    )


class FACECAP_PG_settings(bpy.types.PropertyGroup):
    """Settings of the current take."""

    target: PointerProperty(
        name="Character",
        type=bpy.types.Object,
        poll=_is_face_mesh,
        description="Mesh with shape keys and vertex groups named after the markers",
    )
    take_name: StringProperty(name="Take", description="Name of the take; new actions are named after it")
    markers_path: StringProperty(name="Markers", subtype="FILE_PATH", description="Marker file of the take")
    units: EnumProperty(name="Units", items=UNIT_ITEMS, default="mm")
    fps: FloatProperty(name="FPS", default=60.0, min=1.0, description="Frame rate of the capture")
    marker_collection: PointerProperty(
        name="Marker Collection", type=bpy.types.Collection, description="Collection holding the take's marker empties"
    )
    markers: CollectionProperty(type=FACECAP_PG_marker)
    active_marker: IntProperty(default=0)
    neutral_first: IntProperty(name="First", default=1, description="First frame of the neutral / T-pose range")
    neutral_last: IntProperty(name="Last", default=30, description="Last frame of the neutral / T-pose range")
    strategy: EnumProperty(name="Strategy", items=STRATEGY_ITEMS, default="geometric")
    regularisation: FloatProperty(
        name="Regularisation",
        default=1e-3,
        min=0.0,
        precision=5,
        description="Ridge weight relative to the basis scale: larger values keep weights smaller and steadier",
    )
    sparsity: FloatProperty(
        name="Sparsity",
        default=1e-3,
        min=0.0,
        precision=5,
        description="L1 weight relative to the basis scale: pulls shapes that only explain noise to zero",
    )
    symmetry: FloatProperty(
        name="Symmetry",
        default=0.0,
        min=0.0,
        precision=4,
        description="Coupling of Left/Right shape pairs relative to the basis scale; lets a side with missing markers follow the other",
    )
    smoothing_first: FloatProperty(
        name="Velocity Smoothing",
        default=0.0,
        min=0.0,
        precision=4,
        description="Temporal weight on frame-to-frame change (0 = frames solved independently)",
    )
    smoothing_second: FloatProperty(
        name="Acceleration Smoothing",
        default=0.3,
        min=0.0,
        precision=4,
        description="Temporal weight on the second difference (removes jitter, keeps fast closures)",
    )
    fine_iterations: IntProperty(
        name="Fine Refits",
        default=2,
        min=0,
        max=10,
        description="Hierarchical stabilisation: refits of the head pose on all markers against the solve",
    )
    head_smoothing: FloatProperty(
        name="Head Smoothing",
        default=0.1,
        min=0.0,
        max=1.0,
        unit="TIME_ABSOLUTE",
        description="Half-window in seconds of the zero-phase smoothing of the head pose (0 = off)",
    )
    shapes: CollectionProperty(type=FACECAP_PG_shape)
    active_shape: IntProperty(default=0)
    regions: CollectionProperty(type=FACECAP_PG_region)
    active_region: IntProperty(default=0)
    head_object: PointerProperty(name="Head Motion", type=bpy.types.Object, description="Empty keyed with the removed head motion")
    flagged_frames: IntProperty(name="Flagged Frames", default=0, description="Frames the last stabilisation could not fit")
    last_action: StringProperty(name="Last Action", description="Action created by the last solve")
    last_report: StringProperty(name="Last Result", description="Summary of the last solve")


CLASSES = (FACECAP_PG_marker, FACECAP_PG_shape, FACECAP_PG_region, FACECAP_PG_settings)


def register_properties():
    bpy.types.Scene.facecap = PointerProperty(type=FACECAP_PG_settings)


def unregister_properties():
    del bpy.types.Scene.facecap
