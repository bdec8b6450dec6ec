"""The Gaussian methods: EKF-SLAM (one joint Gaussian) and NASRUKF FastSLAM (square-root UKFs per
feature with an information-weighted pose), with their states and the protocol they share."""

__all__: list[str] = []
