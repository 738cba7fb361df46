"""HTTP service: ``create_app(settings=None)`` builds the FastAPI app that ``adsm serve`` runs."""

from service.api.app import create_app
from service.api.settings import Settings

__all__ = ["Settings", "create_app"]
