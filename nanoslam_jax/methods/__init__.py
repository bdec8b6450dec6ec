"""The filters: the Rao-Blackwellised particle filter shared by all particle methods, the Gaussian
methods (EKF-SLAM, NASRUKF) with their state protocol (:class:`GaussianState`), each method's
nested settings, and the scan driver that runs any of them over a log."""

from nanoslam_jax.methods.maps._association import Association as Association, associate as associate
from nanoslam_jax.methods.maps._landmarks import (
    add_landmarks as add_landmarks,
    ekf_update as ekf_update,
    ekf_update_loglik as ekf_update_loglik,
    gather_window as gather_window,
    init_landmark as init_landmark,
    scatter_window as scatter_window,
    update_slots as update_slots,
)
from nanoslam_jax.methods.maps._management import (
    diameter_update as diameter_update,
    in_view as in_view,
    manage_window as manage_window,
    occluded as occluded,
)
from nanoslam_jax.methods._method_settings import (
    BeamParams as BeamParams,
    IteratedStatic as IteratedStatic,
    NanoParams as NanoParams,
    NanoStatic as NanoStatic,
    NasrukfParams as NasrukfParams,
    NasrukfStatic as NasrukfStatic,
)
from nanoslam_jax.methods._params import (
    MapParams as MapParams,
    Params as Params,
    Static as Static,
    method_static as method_static,
    particle_devices as particle_devices,
    shardable as shardable,
    row_buckets as row_buckets,
    settings_from_config as settings_from_config,
)
from nanoslam_jax.methods.particle._path import (
    ESTIMATES as ESTIMATES,
    ancestral_path as ancestral_path,
    reported_trajectory as reported_trajectory,
)
from nanoslam_jax.methods.particle._prior import (
    compose_prior as compose_prior,
    predict as predict,
    predict_mean as predict_mean,
    relative_prior as relative_prior,
)
from nanoslam_jax.lib._resampling import (
    RESAMPLERS as RESAMPLERS,
    effective_sample_size as effective_sample_size,
    normalise as normalise,
    resample as resample,
)
from nanoslam_jax.methods._scan import (
    AVAILABLE_METHODS as AVAILABLE_METHODS,
    GAUSSIAN_METHODS as GAUSSIAN_METHODS,
    FilterRun as FilterRun,
    MapHistory as MapHistory,
    dead_reckoning as dead_reckoning,
    filter_scan as filter_scan,
    initial_state as initial_state,
    is_gaussian as is_gaussian,
    make_proposal as make_proposal,
    relative_priors as relative_priors,
    reported_map as reported_map,
    resample_count as resample_count,
    run_batch as run_batch,
    run_filter as run_filter,
    stack_params as stack_params,
    text_progress as text_progress,
)
from nanoslam_jax.methods._state import (
    FilterState as FilterState,
    LandmarkMap as LandmarkMap,
    Particles as Particles,
    count_confirmed as count_confirmed,
    init_state as init_state,
)
from nanoslam_jax.methods.particle._step import StepOutput as StepOutput, filter_step as filter_step
from nanoslam_jax.methods.gaussian._gaussian import (
    GaussianState as GaussianState,
    GaussianStepOutput as GaussianStepOutput,
    as_step_output as as_step_output,
)
from nanoslam_jax.methods.gaussian._ekf_slam import (
    EkfSlamState as EkfSlamState,
    init_ekf_state as init_ekf_state,
    ekf_slam_step as ekf_slam_step,
)
from nanoslam_jax.methods.gaussian._nasrukf import fuse_poses as fuse_poses, nasrukf_step as nasrukf_step
from nanoslam_jax.methods.gaussian._nasrukf_state import (
    NasrukfFeatures as NasrukfFeatures,
    NasrukfState as NasrukfState,
    configured_noise as configured_noise,
    init_nasrukf_state as init_nasrukf_state,
)
from nanoslam_jax.methods.gaussian._srukf import (
    SigmaMeasurement as SigmaMeasurement,
    NOISE_ARC_SUMMARY_KEYS as NOISE_ARC_SUMMARY_KEYS,
    NOISE_SUMMARY_KEYS as NOISE_SUMMARY_KEYS,
    adaptive_noise_rows as adaptive_noise_rows,
    adaptive_noise_summary as adaptive_noise_summary,
    adaptive_noise_update as adaptive_noise_update,
    adaptive_process_summary as adaptive_process_summary,
    adaptive_process_update as adaptive_process_update,
    chol_rank_one as chol_rank_one,
    chol_rank_update as chol_rank_update,
    forgetting_weight as forgetting_weight,
    measurement_update as measurement_update,
    noise_estimates as noise_estimates,
    predict_measurement as predict_measurement,
    process_noise_basis as process_noise_basis,
    qr_factor as qr_factor,
    srukf_transform as srukf_transform,
)
