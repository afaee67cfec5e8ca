"""Exports of reconstructed hairstyles: USD BasisCurves, .hair, .data, PLY, .npz and the head OBJ."""

from vid2haircut.export.export import export_files, export_hairstyle, write_obj
from vid2haircut.export.usd import read_usd_curves, write_usd_curves

__all__ = ["export_files", "export_hairstyle", "read_usd_curves", "write_obj", "write_usd_curves"]
