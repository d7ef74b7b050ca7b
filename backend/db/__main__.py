"""``python -m backend.db upgrade [REV]`` | ``downgrade REV`` | ``current`` |
``revision -m MSG [--autogenerate]``, against DRLAAS_DATABASE (see backend.settings)."""

from __future__ import annotations

import argparse

from alembic import command

from backend.settings import load_settings

from .engine import alembic_config, current_revision, downgrade, make_engine, upgrade


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m backend.db", description=__doc__)
    sub = parser.add_subparsers(dest="cmd", required=True)
    up = sub.add_parser("upgrade")
    up.add_argument("revision", nargs="?", default="head")
    down = sub.add_parser("downgrade")
    down.add_argument("revision")
    sub.add_parser("current")
    rev = sub.add_parser("revision")
    rev.add_argument("-m", "--message", required=True)
    rev.add_argument("--autogenerate", action="store_true")
    args = parser.parse_args(argv)

    url = load_settings().database_url
    engine = make_engine(url)
    try:
        if args.cmd == "upgrade":
            upgrade(engine, args.revision)
        elif args.cmd == "downgrade":
            downgrade(engine, args.revision)
        elif args.cmd == "current":
            print(current_revision(engine))  # noqa: T201  (CLI output)
        else:
            cfg = alembic_config(url)
            command.revision(cfg, message=args.message, autogenerate=args.autogenerate)
    finally:
        engine.dispose()


if __name__ == "__main__":
    main()
