"""Skeletons, forward kinematics, marker sets and posing from markers (puppet, hand)."""

from stillcap.body.kinematics import (
    RigidAlignment,
    bone_directions,
    pose_from_bone_directions,
    pose_from_markers,
    rigid_alignment,
    rotation_between,
)
from stillcap.body.markerset import BoneRule, Marker, MarkerSet, MarkerTrajectories
from stillcap.body.skeleton import Animation, Joint, Pose, Skeleton, forward_kinematics

__all__ = [
    "Animation",
    "BoneRule",
    "Joint",
    "Marker",
    "MarkerSet",
    "MarkerTrajectories",
    "Pose",
    "RigidAlignment",
    "Skeleton",
    "bone_directions",
    "forward_kinematics",
    "pose_from_bone_directions",
    "pose_from_markers",
    "rigid_alignment",
    "rotation_between",
]
