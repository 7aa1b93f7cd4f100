"""Shared test task: the plain wheel-space residual on ``analytic``, for the tests of one
mechanism (the defaults are the shipped recipe, whose twist residual on ``feedback``
observes and acts through more than such a test means to see)."""

WHEEL = {
    "residual_scale": 0.1,
    "residual_space": "wheel",
    "residual_base": "analytic",
    "action_filter": 0.0,
    "residual_deadband": 0.0,
    "residual_ramp_s": 0.0,
    "path_tau": 0.0,
}
"""EnvConfig fields: a wheel-space residual of 0.1 · max_rate on ``analytic``, unfiltered,
without deadband, ramp or path error."""

PLAIN_FEEDBACK = {"hold_s": 0.0, "reset": False, "deadband": 0.0}
"""FeedbackConfig fields: the integrator integrates through command changes, never held,
restarted or thresholded."""
