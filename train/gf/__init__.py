"""GroupForward-mini training code: sim dataset loader, network, losses."""
