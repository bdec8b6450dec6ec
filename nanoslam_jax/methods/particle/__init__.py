"""The Rao-Blackwellised particle step shared by every particle method: the prior, the per-row
proposal and updates, weights, management and resampling, and the reported path."""

__all__: list[str] = []
