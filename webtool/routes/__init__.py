"""One router per area of the web tool: pages, health, calibration, designer, live, replay."""
