"""FastAPI gateway: ``backend.api.main.create_app(settings)`` builds it (routers under ``/api``).

Nothing is re-exported here: services and auth sit below the API and never import it
(``.importlinter``), so no import cycle needs a lazy loader.
"""
