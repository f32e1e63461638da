"""The ``calnav`` command line. Each command is declared once, beside its main, and registered in
``eval.parser.COMMANDS``; this file only parses arguments and dispatches, so ``calnav --help``
stays fast (a command's module is imported when it is named, its heavy imports on use)."""
from __future__ import annotations

import argparse
import os
import sys

# torch's OpenMP workers spin after each op and starve Open3D's threads on small machines
# (measured: 400-900 ms instead of 2 ms per segmenter frame on 2 busy cores). Must be set
# before torch is imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from calnav.common.interrupt import sigint_flag
from calnav.eval.arguments import check_args
from calnav.eval.config import ConfigError
from calnav.eval.parser import COMMANDS, build_parser, refuse_moved_flags
from calnav.eval.results_dir import ResultsError


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Parse ``argv`` (default: sys.argv[1:]). Options and KEY=VALUE overrides may be intermixed
    (``objectnav a.b=1 --episodes 0:2 c.d=2``): argparse's ``parse_intermixed_args`` does that,
    but not across subparsers, so the top-level parser only picks the command and the
    command's own parser (built from its declaration, ``eval.arguments.Command``) reads the rest."""
    argv = sys.argv[1:] if argv is None else list(argv)
    name = next((word for word in argv if not word.startswith("-")), None)
    parser = build_parser(name if name in COMMANDS else None)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    if name in COMMANDS:   # before argparse reads the words, which would misread a renamed flag
        refuse_moved_flags(sub.choices[name], argv[argv.index(name) + 1:])
    args, _ = parser.parse_known_args(argv)   # the command (and --help / a bad command exit here)
    rest = argv[argv.index(args.command) + 1:]
    # schema: the command's sections and shorthands, for its config loader (eval.shorthands.load_command_config)
    namespace = argparse.Namespace(command=args.command, schema=COMMANDS.get(args.command).schema(args.command))
    return sub.choices[args.command].parse_intermixed_args(rest, namespace=namespace)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        # a real Ctrl-C, told apart from a plugin's own KeyboardInterrupt (in the preflight's probe too)
        with sigint_flag():
            from calnav.envs.scene import check_cache_dir

            check_cache_dir()   # every command reads or writes the cache
            from calnav.eval.preflight import check_configs

            command = COMMANDS.get(args.command)
            check_args(command, args)   # its flags' declared ranges
            configs = command.load_configs(args)   # every config it runs (all multirun combinations)
            check_configs(configs, command.checks)   # every file and service they name, before anything is written
            status = command.run_main(args, configs)
            if command.status and status:
                return int(status)
    except (ConfigError, ValueError, FileNotFoundError, ResultsError) as exc:
        print(f"calnav {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"calnav {args.command}: interrupted; finished work is kept: rerun the same command to resume",
              file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
