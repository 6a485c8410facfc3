"""One router per resource: jobs, their events, models, and the service itself."""
