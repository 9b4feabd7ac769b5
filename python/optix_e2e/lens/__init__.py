"""The lens and its analysis: the :class:`Lens` model (a validated prescription plus the
engine's ray tracing, PSFs, spots, wavefronts), glass catalogs, surfaces, relative
illumination, MTF, ray footprints, and Zemax import/export (:mod:`.zemax`)."""

from .model import BUNDLED_DIR, BUNDLED_SURROGATES, DEFAULT_RGB_CHANNELS, Lens, LensLoadError, bundled_lenses

__all__ = ["Lens", "LensLoadError", "bundled_lenses", "BUNDLED_DIR", "BUNDLED_SURROGATES", "DEFAULT_RGB_CHANNELS"]
