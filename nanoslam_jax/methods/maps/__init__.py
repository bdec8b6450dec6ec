"""A particle's landmark map: the local window, EKF and unscented landmark updates, data
association and landmark management."""

__all__: list[str] = []
