"""Motion and measurement models with autodiff Jacobians."""

from ._angles import circular_mean as circular_mean, wrap_angle as wrap_angle, wrap_angle_np as wrap_angle_np
from ._motion import (
    MOTION_MODELS as MOTION_MODELS,
    AbstractMotionModel as AbstractMotionModel,
    AbstractRateModel as AbstractRateModel,
    Ackermann as Ackermann,
    RandomWalk as RandomWalk,
    Unicycle as Unicycle,
    motion_model_class as motion_model_class,
    motion_model_from_config as motion_model_from_config,
)
from ._measurement import (
    MEASUREMENT_MODELS as MEASUREMENT_MODELS,
    AbstractMeasurementModel as AbstractMeasurementModel,
    RangeBearing as RangeBearing,
    check_measurement_model as check_measurement_model,
    is_range_bearing as is_range_bearing,
    measurement_model_class as measurement_model_class,
    measurement_model_from_config as measurement_model_from_config,
)
from ._range_bearing import (
    innovation as innovation,
    inverse_range_bearing as inverse_range_bearing,
    inverse_range_bearing_jacobians as inverse_range_bearing_jacobians,
    range_bearing as range_bearing,
    range_bearing_components as range_bearing_components,
    range_bearing_jacobian_components as range_bearing_jacobian_components,
    range_bearing_jacobians as range_bearing_jacobians,
)
from ._vehicle import (
    VehicleParams as VehicleParams,
    centre_speed as centre_speed,
    vehicle_jacobians as vehicle_jacobians,
    vehicle_move as vehicle_move,
    vehicle_rates as vehicle_rates,
    vehicle_step as vehicle_step,
)

__all__ = [
    "AbstractMotionModel",
    "AbstractRateModel",
    "Ackermann",
    "Unicycle",
    "RandomWalk",
    "MOTION_MODELS",
    "motion_model_class",
    "motion_model_from_config",
    "AbstractMeasurementModel",
    "RangeBearing",
    "MEASUREMENT_MODELS",
    "is_range_bearing",
    "check_measurement_model",
    "measurement_model_class",
    "measurement_model_from_config",
    "VehicleParams",
    "vehicle_step",
    "vehicle_move",
    "vehicle_rates",
    "vehicle_jacobians",
    "centre_speed",
    "range_bearing",
    "range_bearing_components",
    "range_bearing_jacobians",
    "range_bearing_jacobian_components",
    "inverse_range_bearing",
    "inverse_range_bearing_jacobians",
    "innovation",
    "wrap_angle",
    "wrap_angle_np",
    "circular_mean",
]
