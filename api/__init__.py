"""Wire schemas shared by the server, the workers and the SDK (pydantic only; never torch)."""
