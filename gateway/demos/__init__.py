"""`compgw demo`: the tour, commissioning and seed 003."""
