"""Job records shared by the server and the workers: tables, migrations and repositories.

Both sides of the service import this (the server to accept and report jobs, the workers to
claim and run them), so it lives beside the wire schemas and imports neither FastAPI nor torch:
only SQLAlchemy Core. The same code serves SQLite (embedded) and PostgreSQL (scale-out).
"""
