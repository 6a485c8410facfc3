"""``sparsesplat keys create NAME | list | revoke ID``: manage API keys (run on the server)."""

from __future__ import annotations

import argparse
import datetime
import json
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands create, list, revoke."""
    sub = parser.add_subparsers(dest="action", required=True)
    create = sub.add_parser("create", help="create a key; it is printed once, keep it")
    create.add_argument("name", help="who or what the key is for")
    sub.add_parser("list", help="list keys (never the keys themselves)")
    revoke = sub.add_parser("revoke", help="revoke a key by id")
    revoke.add_argument("key_id")
    parser.add_argument("--json", action="store_true", help="machine-readable output")


def run(args: argparse.Namespace) -> int:
    """0 on success, 1 when revoking an unknown key."""
    from sparsesplat.api.settings import load_settings
    from sparsesplat.api.store.database import make_engine, migrate
    from sparsesplat.api.store.keys import KeyStore

    settings = load_settings()
    assert settings.database_url is not None
    engine = make_engine(settings.database_url)
    migrate(engine)
    keys = KeyStore(engine)
    if args.action == "create":
        info, key = keys.create(args.name)
        if args.json:
            print(json.dumps({"id": info.id, "name": info.name, "key": key}))
        else:
            print(f"created {info.id} ({info.name}). The key, shown only now:\n{key}")
        return 0
    if args.action == "list":
        rows = keys.all()
        if args.json:
            for r in rows:
                print(json.dumps({"id": r.id, "name": r.name, "created_at": r.created_at,
                                  "revoked": r.revoked}))  # fmt: skip
        else:
            for r in rows:
                when = datetime.datetime.fromtimestamp(r.created_at, datetime.UTC)
                status = "revoked" if r.revoked else "active"
                print(f"{r.id}  {status:8}  {when:%Y-%m-%d %H:%M}  {r.name}")
        return 0
    if keys.revoke(args.key_id):
        print(f"revoked {args.key_id}")
        return 0
    print(f"sparsesplat keys: no active key {args.key_id!r}", file=sys.stderr)
    return 1
