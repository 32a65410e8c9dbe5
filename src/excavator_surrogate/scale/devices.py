"""Re-export of :mod:`excavator_surrogate.devices` (the device helper lives at the package root)."""

from ..devices import DEVICE_CHOICES, cuda_usable, device_label, resolve_device

__all__ = ["DEVICE_CHOICES", "cuda_usable", "device_label", "resolve_device"]
