"""Names shared by every stage: the six perception cues and the body's joints.

Order matters: arrays indexed by cue or joint use exactly these orders.
"""

CUE_NAMES: tuple[str, ...] = ("head", "hand_l", "hand_r", "foot_l", "foot_r", "torso")

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

# The joint that each cue measures, in CUE_NAMES order.
CUE_JOINTS: tuple[str, ...] = ("head", "hand_l", "hand_r", "foot_l", "foot_r", "torso")
CUE_JOINT_INDEX: tuple[int, ...] = tuple(JOINT_NAMES.index(j) for j in CUE_JOINTS)

# Cues found by the skin model vs the shoe model vs the silhouette.
SKIN_CUES = ("head", "hand_l", "hand_r")
SHOE_CUES = ("foot_l", "foot_r")
