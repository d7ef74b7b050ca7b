"""DRLaaS platform services: chain client (backend.chain) and the other service adapters."""
