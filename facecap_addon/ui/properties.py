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

from . import properties_video
from .option_props import from_option

STRATEGY_ITEMS = [
    ("semantic", "Semantic", "Solve what the actor does, shape by shape, against the actor's own face as well as it "
     "is known (calibration poses, a performer profile, the human template, else the character's shapes, "
     "normalised), and key it on the shapes of the same name"),
    ("geometric", "Geometric", "Solve marker deltas against the character's shape keys at the bound vertices"),
    ("calibrated", "Calibrated", "Solve the actor's calibration poses, then map them to the character's shapes "
     "(characters whose proportions differ from the actor's)"),
    ("parallel", "Parallel", "Copy already-solved weights (Live Link Face / ARKit / MediaPipe CSV) to the shape keys "
     "by name or mapping table"),
    ("linear", "Linear", "Linear map (cloning matrix) learned from frames you posed on the character"),
    ("rbf", "RBF", "Radial-basis interpolation between frames you posed on the character (Pyun)"),
    ("pca", "PCA", "Basis learned from the performance itself, mapped by frames you posed on the character"),
    ("refine", "Refine", "Calibrated, with the actor's pose library refined on this take (Choe & Ko)"),
]
UNSEEN_ITEMS = [
    ("rest", "Rest", "Shapes that move no marker (gaze on skin markers, the tongue) are held at 0"),
    ("solve", "Solve", "Solve every shape, even those no marker sees"),
]
CALIB_SOURCE_ITEMS = [
    ("COLLECTION", "Collection", "Calibration markers are empties in a collection (an imported calibration take)"),
    ("FILE", "File", "Calibration markers are read from a capture file"),
]
ALIGN_ITEMS = [
    ("rigid", "Rigid", "Rotate the take's neutral onto the calibration neutral"),
    ("similarity", "Similarity", "Rotate and scale the take's neutral onto the calibration neutral"),
    ("none", "None", "The take and the calibration share a head frame"),
]
#: The ROM sheets (``[calibration] sequence``): none (poses typed as frame ranges), or a built-in sheet.
ROM_SHEET_ITEMS = [
    ("NONE", "None", "No range-of-motion session: calibration poses are frame ranges you type"),
    ("facecap-24", "facecap-24", "A ROM of 24 natural expressions (2-3 minutes) that ask every ARKit shape; "
     "Find Poses marks their holds in the calibration take"),
    ("arkit-51", "arkit-51", "A ROM of one pose per ARKit shape (trained performers, about 5 minutes); "
     "Find Poses marks their holds in the calibration take"),
]
CURVE_ITEMS = [
    ("linear", "Linear", "Values as they are"),
    ("smoothstep", "Smoothstep", "Ease in and out (3x^2 - 2x^3)"),
    ("gamma", "Gamma", "x^gamma: gamma < 1 boosts small values, > 1 suppresses them"),
]
KERNEL_ITEMS = [(k, k.replace("_", " ").title(), f"RBF kernel {k}") for k in (
    "thin_plate_spline", "cubic", "quintic", "linear", "gaussian", "multiquadric", "inverse_multiquadric",
    "inverse_quadratic")]
PCA_MODE_ITEMS = [
    ("related", "Related Basis", "Regression from the performance's principal components to the posed weights"),
    ("posed", "Posed Basis Frames", "Non-negative blend of the posed basis frames (Chuang & Bregler)"),
]
BINDING_ITEMS = [
    ("vertex_groups", "Vertex Groups", "Each marker samples the vertex group of the same name"),
    ("map", "Map", "A marker,target CSV names each marker's vertex group, vertex or point"),
    ("nearest", "Nearest", "The actor's neutral is aligned to the face (by landmarks, or automatically) and each "
     "marker bound to the nearest surface point"),
]
UNIT_ITEMS = [
    ("mm", "Millimetres", "Marker coordinates are in millimetres"),
    ("cm", "Centimetres", "Marker coordinates are in centimetres"),
    ("m", "Metres", "Marker coordinates are in metres"),
]


def _is_face_mesh(_self, obj):
    return obj.type == "MESH" and obj.data.shape_keys is not None


#: The Solve panel's target: the shape keys (none), or a rig preset (``[rig] preset``).
RIG_PRESET_ITEMS = (
    ("NONE", "Shape Keys", "Solve the character's shape keys"),
    ("rigify_face", "Rigify Face", "Solve the face controls of a generated Rigify rig"),
    ("arkit_sliders", "ARKit Sliders", "Solve the ARKit-named sliders (custom properties) of a control object"),
    ("shape_keys", "Shape Keys + Correctives", "Solve the undriven shape keys; corrective keys fire through their drivers"),
)
RIG_METHOD_ITEMS = (
    ("probed", "Probed", "Evaluate the rig around rest and fit a model with its pairwise terms"),
    ("poses", "Pose Library", "One control pose per shape, from an action with named pose markers"),
)

class FACECAP_PG_marker(bpy.types.PropertyGroup):
    """One imported marker; ``name`` is the marker name."""

    stable: BoolProperty(
        name="Stable",
        description="Moves only with the head (forehead, temples, nose bridge): used to remove head motion",
        default=False,
    )
    gaps: IntProperty(name="Gaps", description="Missing samples in the take", default=0)
    stable_score: FloatProperty(
        name="Stable Score", default=-1.0,
        description="Motion synchronous with the expression, in noise units (Suggest Stable Markers; "
        "about 1 or less = rigid; -1 = not scored)",
    )
    bound: BoolProperty(name="Bound", default=False,
                        description="Bound to a point of the character by the last binding (a read-out)")
    bind_distance: FloatProperty(name="Binding Distance", default=-1.0, unit="NONE",
                                 description="The marker's distance to the character's surface when bound, mm "
                                 "(-1: not measured)")


class FACECAP_PG_landmark(bpy.types.PropertyGroup):
    """A landmark of the nearest binding: ``name`` is the marker, placed at ``vertex_group``'s centroid."""

    vertex_group: StringProperty(name="Vertex Group",
                                 description="Vertex group of the character (or a vertex index) where the marker sits")


class FACECAP_PG_shape(bpy.types.PropertyGroup):
    """Solve options of one shape key; ``name`` is the shape key's name."""

    lock: BoolProperty(name="Lock", description="Hold this shape at the lock value in the solve (animator-owned)")
    lock_value: FloatProperty(name="Value", default=0.0, description="Value a locked shape is held at")
    lower: FloatProperty(name="Min", default=0.0, description="Lower bound of the solved weight")
    upper: FloatProperty(name="Max", default=1.0, description="Upper bound of the solved weight")
    region: StringProperty(name="Region", description="Region solving this shape (empty: the whole face)")
    # everyday controls, applied to the solved weights before they are keyed (solvers/shape_controls.py)
    gain: FloatProperty(name="Gain", default=1.0, description="Solved weight times this")
    offset: FloatProperty(name="Offset", default=0.0, description="Added after the gain")
    use_clamp: BoolProperty(name="Clamp", default=False, description="Clamp the keyed weight to [Clamp Min, Clamp Max]")
    clamp_min: FloatProperty(name="Clamp Min", default=0.0)
    clamp_max: FloatProperty(name="Clamp Max", default=1.0)
    curve: EnumProperty(
        name="Curve", default="linear",
        items=[("linear", "Linear", "Unchanged"),
               ("smoothstep", "Smoothstep", "Eases in and out (3x^2 - 2x^3 on [0, 1])"),
               ("gamma", "Gamma", "sign(x)|x|^g: g < 1 boosts small values, g > 1 suppresses them")],
    )
    gamma: FloatProperty(name="Gamma", default=1.0, min=0.05, max=20.0, description="Exponent of the gamma curve")
    smoothing: FloatProperty(name="Smoothing", default=0.0, min=0.0, unit="TIME_ABSOLUTE",
                             description="Extra zero-phase smoothing of this shape (half-window, seconds)")
    mute: BoolProperty(name="Mute", default=False, description="Key this shape at 0")


class FACECAP_PG_tuning_frame(bpy.types.PropertyGroup):
    """A frame the animator corrected; its final (solve + animator layer) weights teach the retune."""

    frame: IntProperty(name="Frame")
    change: FloatProperty(name="Change", default=0.0,
                          description="RMS of the animator's change over the shapes at this frame (when added)")
    error: FloatProperty(name="Error", default=-1.0,
                         description="RMS of solve minus correction after the last retune (-1: not retuned yet)")


class FACECAP_PG_library_version(bpy.types.PropertyGroup):
    """A stored library version (its arrays are kept in the scene's ``facecap_libraries`` property)."""

    parent: StringProperty(name="Parent", description="Version this one was tuned from (empty: the original)")
    strategy: EnumProperty(items=STRATEGY_ITEMS, **from_option("solve.strategy", label="Strategy"))
    kind: StringProperty(name="Kind", description="actor_basis, character_basis or examples")
    created: StringProperty(name="Created")
    corrected_before: FloatProperty(name="Before", default=-1.0, description="RMS error on the corrected frames before")
    corrected_after: FloatProperty(name="After", default=-1.0, description="RMS error on the corrected frames after")
    others_moved: FloatProperty(name="Others Moved", default=-1.0,
                                description="Relative RMS change of the weights on every other frame")
    note: StringProperty(name="Note")


class FACECAP_PG_region(bpy.types.PropertyGroup):
    """A face region: its shapes are solved only from its markers; ``name`` is the region's name."""

    markers: StringProperty(
        name="Markers", description="Comma-separated marker name patterns, e.g. brow*, eye*, forehead*, head_*"
    )


class FACECAP_PG_pose(bpy.types.PropertyGroup):
    """A calibration pose held over a frame range; ``name`` is the pose (several rows may share one)."""

    first: IntProperty(name="First", default=1, description="First frame of the held pose")
    last: IntProperty(name="Last", default=1, description="Last frame of the held pose")
    split: BoolProperty(name="Split", default=False,
                        description="Performed on both sides at once: split into <pose>Left / <pose>Right by marker side")


class FACECAP_PG_mapping(bpy.types.PropertyGroup):
    """One mapping-table row: a source channel drives a character shape with a gain."""

    source: StringProperty(name="Source", description="Actor pose or capture channel")
    target: StringProperty(name="Target", description="Character shape key")
    gain: FloatProperty(name="Gain", default=1.0, description="Contribution of the source to the target")


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
    binding_mode: EnumProperty(items=BINDING_ITEMS, **from_option("binding.mode", label="Binding"))
    binding_map: StringProperty(name="Map", subtype="FILE_PATH",
                                description="marker,target CSV (target: vertex group, vertex index or x,y,z)")
    binding_landmarks: CollectionProperty(type=FACECAP_PG_landmark)
    active_binding_landmark: IntProperty(default=0)
    binding_max_distance: FloatProperty(**from_option("binding.max_distance_mm", label="Max Distance (mm)"))
    binding_summary: StringProperty(name="Binding", description="Summary of the last binding (a read-out)")
    neutral_first: IntProperty(name="First", default=1, description="First frame of the neutral / T-pose range")
    neutral_last: IntProperty(name="Last", default=30, description="Last frame of the neutral / T-pose range")
    strategy: EnumProperty(items=STRATEGY_ITEMS, **from_option("solve.strategy", label="Strategy"))
    # -- semantic -------------------------------------------------------------------------------
    unseen_shapes: EnumProperty(items=UNSEEN_ITEMS, **from_option("solve.unseen_shapes", label="Unseen Shapes"))
    exclusive: BoolProperty(**from_option("solve.exclusive", label="Opposing Shapes Exclusive"))
    actor_profile: StringProperty(subtype="FILE_PATH", **from_option("actor.profile", label="Performer Profile"))
    actor_template: StringProperty(**from_option("actor.template", label="Human Template"))
    actor_tier: StringProperty(name="Actor", description="What the last semantic solve knew of the actor's face "
                               "(a read-out)")
    rig_preset: EnumProperty(items=RIG_PRESET_ITEMS, default="NONE", **from_option("rig.preset", label="Target"))
    rig_object: PointerProperty(type=bpy.types.Object, **from_option("rig.object", label="Rig"))
    rig_method: EnumProperty(items=RIG_METHOD_ITEMS, **from_option("rig.method", label="Method"))
    rig_poses: PointerProperty(type=bpy.types.Action, **from_option("rig.poses", label="Poses"))
    rig_nonlinear: BoolProperty(**from_option("rig.nonlinear", label="Nonlinear"))
    rig_refine: BoolProperty(**from_option("rig.refine", label="Refine Through Rig"))
    rig_probes: IntProperty(**from_option("rig.probes", label="Random Probes"))
    regularisation: FloatProperty(precision=5, **from_option("solve.regularisation", label="Regularisation"))
    sparsity: FloatProperty(precision=5, **from_option("solve.sparsity", label="Sparsity"))
    symmetry: FloatProperty(precision=4, **from_option("solve.symmetry", label="Symmetry"))
    smoothing_first: FloatProperty(precision=4, **from_option("solve.smoothing", index=0, label="Velocity Smoothing"))
    smoothing_second: FloatProperty(precision=4, **from_option("solve.smoothing", index=1, label="Acceleration Smoothing"))
    fine_iterations: IntProperty(**from_option("stabilise.fine_iterations", label="Fine Refits"))
    head_smoothing: FloatProperty(unit="TIME_ABSOLUTE", **from_option("stabilise.head_smoothing", label="Head Smoothing"))
    shapes: CollectionProperty(type=FACECAP_PG_shape)
    active_shape: IntProperty(default=0)
    regions: CollectionProperty(type=FACECAP_PG_region)
    active_region: IntProperty(default=0)
    # -- calibrated / refine ------------------------------------------------------------------
    calib_source: EnumProperty(name="Calibration", items=CALIB_SOURCE_ITEMS, default="COLLECTION")
    calib_collection: PointerProperty(name="Calibration Markers", type=bpy.types.Collection,
                                      description="Collection holding the calibration take's marker empties")
    calib_path: StringProperty(name="Calibration File", subtype="FILE_PATH", description="Calibration take (capture file)")
    calib_units: EnumProperty(name="Units", items=UNIT_ITEMS, default="mm", description="Units of the calibration file")
    calib_neutral_first: IntProperty(name="First", default=1, description="First frame of the calibration neutral")
    calib_neutral_last: IntProperty(name="Last", default=30, description="Last frame of the calibration neutral")
    calib_poses: CollectionProperty(type=FACECAP_PG_pose)
    active_calib_pose: IntProperty(default=0)
    calib_pose_name: StringProperty(name="Pose Name", default="jawOpen",
                                    description="Name of the next pose added from the timeline")
    calib_align: EnumProperty(items=ALIGN_ITEMS, **from_option("calibration.align", label="Align"))
    calib_sheet: EnumProperty(items=ROM_SHEET_ITEMS, **from_option("calibration.sequence", label="ROM Sheet",
                                                                  default="NONE"))
    calib_guide: StringProperty(name="Guide", subtype="FILE_PATH",
                                description="The weights (a Live Link Face CSV) of a guide the performer followed in "
                                "the calibration take (a landmark take): Save Performer Profile adds that take to the "
                                "fusion map for this performer and camera")
    # -- mapping (calibrated, refine, parallel) -----------------------------------------------
    mapping: CollectionProperty(type=FACECAP_PG_mapping)
    active_mapping: IntProperty(default=0)
    mapping_aliases: BoolProperty(**from_option("mapping.aliases", label="Aliases"))
    # -- parallel -----------------------------------------------------------------------------
    weights_path: StringProperty(name="Weights File", subtype="FILE_PATH",
                                 description="Solved weights: Live Link Face / ARKit / MediaPipe CSV")
    parallel_gain: FloatProperty(**from_option("mapping.gain", label="Gain"))
    parallel_offset: FloatProperty(**from_option("mapping.offset", label="Offset"))
    parallel_curve: EnumProperty(name="Curve", items=CURVE_ITEMS, default="linear")
    parallel_gamma: FloatProperty(name="Gamma", default=1.0, min=0.05, description="Exponent of the gamma curve")
    parallel_mirror: BoolProperty(**from_option("mapping.mirror", label="Mirror"))
    parallel_use_neutral: BoolProperty(name="Neutral Offset", default=False,
                                       description="Subtract the median of the source over a neutral frame range")
    parallel_neutral_first: IntProperty(name="First", default=1)
    parallel_neutral_last: IntProperty(name="Last", default=30)
    # -- examples (linear, rbf, pca) ------------------------------------------------------------
    examples_action: PointerProperty(name="Examples", type=bpy.types.Action,
                                     description="Action on the character's shape keys whose keyed frames are the posed examples")
    ridge: FloatProperty(precision=6, **from_option("examples.ridge", label="Ridge"))
    rbf_kernel: EnumProperty(items=KERNEL_ITEMS, **from_option("examples.kernel", label="Kernel"))
    rbf_smoothing: FloatProperty(precision=4, **from_option("examples.rbf_smoothing", label="Smoothing"))
    rbf_degree: IntProperty(**from_option("examples.degree", label="Tail Degree"))
    rbf_far: FloatProperty(**from_option("examples.far", label="Far", min=0.01))
    n_components: IntProperty(name="Components", default=0, min=0, description="Principal components (0 = default)")
    pca_mode: EnumProperty(items=PCA_MODE_ITEMS, **from_option("pca.mode", label="Mode"))
    pca_ica: BoolProperty(**from_option("pca.ica", label="ICA"))
    pca_n_basis: IntProperty(**from_option("pca.n_basis", label="Basis Components"))
    pca_variance: FloatProperty(**from_option("pca.variance", label="Variance", min=0.01))
    # -- refine ----------------------------------------------------------------------------------
    refine_max_iterations: IntProperty(**from_option("refine.max_iterations", label="Iterations"))
    refine_tol: FloatProperty(precision=5, **from_option("refine.tol", label="Tolerance"))
    refine_stiffness: FloatProperty(precision=5, **from_option("refine.stiffness", label="Stiffness"))
    head_object: PointerProperty(name="Head Motion", type=bpy.types.Object, description="Empty keyed with the removed head motion")
    flagged_frames: IntProperty(name="Flagged Frames", default=0, description="Frames the last stabilisation could not fit")
    unreliable_frames: IntProperty(name="Unreliable Frames", default=0,
                                   description="Frames where too few stable markers agreed in the last stabilisation")
    # -- stabilise / neutral / master / align (issue 4) -----------------------------------------
    stabilise_mode: EnumProperty(
        items=[("rigid", "Rigid", "Rotation and translation per frame"),
               ("similarity", "Similarity", "Also a uniform scale per frame (captures from different days)")],
        **from_option("stabilise.mode", label="Fit"),
    )
    auto_stable: BoolProperty(name="Auto Stable Set", default=False,
                              description="Suggest the stable markers from the take at every solve")
    stable_gap: FloatProperty(name="Score Gap", default=0.0,
                              description="Score ratio between the suggested set and the next marker (>= 2: clear)")
    neutral_mode: EnumProperty(
        name="Neutral", default="RANGE",
        items=[("RANGE", "Range", "Robust average of one frame range"),
               ("RANGES", "Start + End", "Start and end T-pose ranges"),
               ("DETECT", "Detect", "The most neutral frames: the pose the face holds longest"),
               ("FILE", "File", "A neutral captured in a separate file")],
    )
    neutral_end_first: IntProperty(name="End First", default=1, description="First frame of the end T-pose")
    neutral_end_last: IntProperty(name="End Last", default=30, description="Last frame of the end T-pose")
    neutral_file: StringProperty(name="Neutral File", subtype="FILE_PATH", description="Separately captured neutral")
    use_master: BoolProperty(name="Master T-Pose", default=False,
                             description="Normalise the take to the performer's master T-pose stored in this .blend")
    master_data: StringProperty(name="Master Data", description="Master T-pose (JSON: names, positions in metres)")
    master_source: StringProperty(name="Master Source", description="Where the stored master T-pose came from")
    landmarks: StringProperty(name="Landmarks", default="",
                              description="Comma-separated marker patterns the master alignment uses "
                              "(empty: eye and mouth corners)")
    align_regions: BoolProperty(name="Regional Scale", default=False,
                                description="Align upper and lower face to the character with separate scales")
    head_target: PointerProperty(name="Head Target", type=bpy.types.Object,
                                 description="Character head object (or armature) keyed with the head motion")
    head_bone: StringProperty(name="Bone", description="Bone of the head target armature (empty: the object)")
    last_action: StringProperty(name="Last Action", description="Action created by the last solve")
    video: PointerProperty(type=properties_video.FACECAP_PG_video)  # 2D takes: projection, Track Clip options
    # -- tuning: the animator feedback loop (issue 7) --------------------------------------------
    tuning_frames: CollectionProperty(type=FACECAP_PG_tuning_frame)
    tuning_index: IntProperty(name="Tuning Frame", default=0)
    tune_auto_mu: BoolProperty(name="Automatic Prior", default=True,
                               description="Choose the prior strength by leave-one-frame-out over the corrections")
    tune_mu: FloatProperty(name="Prior (mu)", default=3.0, min=1e-3,
                           description="Pull of the library towards the current one, in frames at full weight")
    library_versions: CollectionProperty(type=FACECAP_PG_library_version)
    library_index: IntProperty(name="Library Version", default=0)
    library_active: StringProperty(name="Active Library",
                                   description="Library version the solve uses (empty: the original)")
    worst_last: IntProperty(name="Last Worst Frame", default=-1_000_000,
                            description="Frame the last Next Worst Frame jump landed on")
    worst_spread: IntProperty(name="Spread", default=5, min=0,
                              description="Jump to Worst skips frames this close to a worse one")
    last_report: StringProperty(name="Last Result", description="Summary of the last solve")


#: Sidebar settings that are not take-config options, and why (every other setting is an option's
#: control: ``solvers.options``; a test checks both directions).
SIDEBAR_ONLY = {
    "marker_collection": "the imported take's marker empties (a config names the file)",
    "head_object": "the empty Stabilise keys with the head motion (a result)",
    "flagged_frames": "a read-out of the last stabilisation",
    "unreliable_frames": "a read-out of the last stabilisation",
    "stable_gap": "a read-out of Suggest Stable Markers",
    "last_action": "a read-out: the action the last solve created",
    "last_report": "a read-out: the last solve's summary",
    "actor_tier": "a read-out: what the last semantic solve knew of the actor's face",
    "video": "the group of video settings (its own settings are checked one by one)",
    "tuning_index": "list selection",
    "library_index": "list selection",
    "worst_last": "state of Next Worst Frame",
    "worst_spread": "an option of Next Worst Frame (an interactive tool)",
    "active_marker": "list selection",
    "active_binding_landmark": "list selection",
    "binding_summary": "a read-out: the last binding's summary",
    "active_shape": "list selection",
    "active_region": "list selection",
    "active_calib_pose": "list selection",
    "active_mapping": "list selection",
    "video.max_points": "Track Clip Footage's option (the `track` command has its own config)",
    "video.method": "Track Clip Footage's option (the `track` command has its own config)",
}

CLASSES = (FACECAP_PG_marker, FACECAP_PG_landmark, FACECAP_PG_shape, FACECAP_PG_region, FACECAP_PG_pose, FACECAP_PG_mapping,
           FACECAP_PG_tuning_frame, FACECAP_PG_library_version, FACECAP_PG_settings)


def register_properties():
    bpy.types.Scene.facecap = PointerProperty(type=FACECAP_PG_settings)


def unregister_properties():
    del bpy.types.Scene.facecap
