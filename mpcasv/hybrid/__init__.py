"""The papers' hybrid controllers: safety-domain geometry, hybrid-system form, controllers."""
