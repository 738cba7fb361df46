"""Sub-pixel refinement of integer disparities."""

from service.refinement.subpixel import refine_subpixel

__all__ = ["refine_subpixel"]
