"""The one owner of the cue and joint orders: names, indices and pairs.

Arrays indexed by cue or joint use exactly these orders; code elsewhere indexes them with
the constants below (plain ints, so numba kernels see them as compile-time constants),
never with a literal.
"""

CUE_NAMES: tuple[str, ...] = ("head", "hand_l", "hand_r", "foot_l", "foot_r", "torso")
N_CUES = len(CUE_NAMES)
# cue name -> index in CUE_NAMES
CUE_INDEX: dict[str, int] = {name: i for i, name in enumerate(CUE_NAMES)}
C_HEAD = CUE_INDEX["head"]
C_HAND_L = CUE_INDEX["hand_l"]
C_HAND_R = CUE_INDEX["hand_r"]
C_FOOT_L = CUE_INDEX["foot_l"]
C_FOOT_R = CUE_INDEX["foot_r"]
C_TORSO = CUE_INDEX["torso"]
# Left/right pairs of cues (left, right): the labels a single view cannot be sure of.
LR_PAIRS: tuple[tuple[int, int], ...] = ((C_HAND_L, C_HAND_R), (C_FOOT_L, C_FOOT_R))
# The hands and feet (the cues of LR_PAIRS), in CUE_NAMES order.
LIMB_CUES: tuple[int, ...] = tuple(sorted(c for pair in LR_PAIRS for c in pair))

# Body joints, world positions in metres. Semantics (the studio's truth and the body
# model agree on them):
#   pelvis      midpoint of the two hip joints (the root)
#   torso       centre of the trunk: midpoint of pelvis and neck (the torso cue)
#   neck        base of the neck, between the shoulders
#   head        centre of the head (the head cue)
#   shoulder/elbow/wrist  joint centres
#   hand        centre of the hand, wrist -> fingertips midpoint (the hand cue)
#   hip/knee/ankle        joint centres
#   foot        centre of the foot/shoe, midpoint of heel and toe tip (the foot cue)
JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "torso", "neck", "head",
    "shoulder_l", "elbow_l", "wrist_l", "hand_l",
    "shoulder_r", "elbow_r", "wrist_r", "hand_r",
    "hip_l", "knee_l", "ankle_l", "foot_l",
    "hip_r", "knee_r", "ankle_r", "foot_r",
)

# The joint that each cue measures, in CUE_NAMES order (the joint of the same name).
CUE_JOINTS: tuple[str, ...] = CUE_NAMES
N_JOINTS = len(JOINT_NAMES)
# joint name -> index in JOINT_NAMES
J: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}
CUE_JOINT_INDEX: tuple[int, ...] = tuple(J[j] for j in CUE_JOINTS)

# Cues found by the skin model vs the shoe model vs the silhouette.
SKIN_CUES = ("head", "hand_l", "hand_r")
SHOE_CUES = ("foot_l", "foot_r")
SKIN_CUE_INDEX: tuple[int, ...] = tuple(CUE_INDEX[c] for c in SKIN_CUES)
SHOE_CUE_INDEX: tuple[int, ...] = tuple(CUE_INDEX[c] for c in SHOE_CUES)
