"""Rendezvous map exchange (SPEC §4): relative pose, message format, channel, polylines.

numpy only; the per-robot SLAM and the env wire these parts together.
"""

from polyslam_env.comms.channel import Channel, ChannelConfig, Counters, Delivered, Expired
from polyslam_env.comms.exchange import (
    DeliveredMessage,
    ExchangeStep,
    PayloadSizes,
    RendezvousExchange,
)
from polyslam_env.comms.messages import (
    GridMessage,
    Header,
    Message,
    PointsMessage,
    PolynomialMessage,
    PolynomialRecord,
    decode,
    encode,
    encode_grid,
    encode_points,
    encode_polynomials,
    payload_size,
)
from polyslam_env.comms.polyline import piecewise_linear, polyline_points
from polyslam_env.comms.relative_pose import (
    frame_transform,
    frame_transform_with_jacobian,
    relative_pose,
    relative_pose_covariance,
    relative_pose_with_jacobian,
)

__all__ = [
    "Channel",
    "ChannelConfig",
    "Counters",
    "Delivered",
    "DeliveredMessage",
    "ExchangeStep",
    "Expired",
    "GridMessage",
    "Header",
    "Message",
    "PayloadSizes",
    "PointsMessage",
    "PolynomialMessage",
    "PolynomialRecord",
    "RendezvousExchange",
    "decode",
    "encode",
    "encode_grid",
    "encode_points",
    "encode_polynomials",
    "frame_transform",
    "frame_transform_with_jacobian",
    "payload_size",
    "piecewise_linear",
    "polyline_points",
    "relative_pose",
    "relative_pose_covariance",
    "relative_pose_with_jacobian",
]
