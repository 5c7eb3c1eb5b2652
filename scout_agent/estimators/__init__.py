"""Proprioceptive terrain estimators: slip, Cost of Transport, GIA stability margins, elevation, and their pipeline."""

from __future__ import annotations

from .cot import CotConfig, CotMeter, cot_from_sums, joint_power
from .elevation import foothold_world, plane_from_moments, plane_moments, slope_deg, terrain_normal
from .pipeline import EstimatorPipeline, PipelineConfig, TickEstimates, quat_to_matrix, record
from .slip import SlipConfig, SlipDetector, SlipTick, delta_p_paper, delta_p_vector, delta_v
from .stability import gia_from_forces, gia_from_imu, margins, margins_per_face, order_ccw

__all__ = [
    "CotConfig",
    "CotMeter",
    "EstimatorPipeline",
    "PipelineConfig",
    "SlipConfig",
    "SlipDetector",
    "SlipTick",
    "TickEstimates",
    "cot_from_sums",
    "delta_p_paper",
    "delta_p_vector",
    "delta_v",
    "foothold_world",
    "gia_from_forces",
    "gia_from_imu",
    "joint_power",
    "margins",
    "margins_per_face",
    "order_ccw",
    "plane_from_moments",
    "plane_moments",
    "quat_to_matrix",
    "record",
    "slope_deg",
    "terrain_normal",
]
