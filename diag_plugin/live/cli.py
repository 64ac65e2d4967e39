"""``diag run``: the live plug-in (see :mod:`diag_plugin.live.loop`)."""

import argparse


def add_commands(sub) -> None:
    p = sub.add_parser(
        "run",
        help="run the live plug-in (no --config: the embedded plant with a scripted fault)",
        description=(
            "Run the live loop: poll, store in the historian, diagnose, publish (OPC UA and "
            "Modbus). Without --config: the embedded default, a simulated valve plant served "
            "as a Modbus PLC with a scripted fault (f14, P0 sensor) raised, acknowledged by a "
            "scripted operator and cleared; its data, history and example unit live in --data."
        ),
    )
    p.add_argument(
        "--config",
        metavar="PLANT_TOML",
        help="plant.toml: units, Modbus/OPC UA sources, outputs (docs/reference/live.md)",
    )
    p.add_argument(
        "--data", default="diag-data", metavar="DIR", help="embedded data dir (no --config)"
    )
    p.add_argument(
        "--cycle",
        type=float,
        default=0.25,
        metavar="S",
        help="wall-clock seconds per cycle; the embedded plant's 10 s samples run this fast",
    )
    p.add_argument(
        "--duration", type=float, default=0.0, metavar="S", help="stop after S seconds (0: never)"
    )
    p.add_argument("--plc-port", type=int, default=5021, help="embedded plant's Modbus PLC port")
    p.add_argument("--modbus-port", type=int, default=5020, help="Modbus status server port")
    p.add_argument("--opcua-port", type=int, default=4840, help="OPC UA server port")
    p.add_argument(
        "--flush-every", type=int, default=20, metavar="N", help="historian write every N cycles"
    )
    p.add_argument("--plain", action="store_true", help="print event lines only (no live table)")
    p.add_argument(
        "--check",
        action="store_true",
        help="with --config: check plant.toml, its files and units, then exit (0 sound, 2 not)",
    )
    p.add_argument(
        "--hash-password",
        action="store_true",
        help="read a password (twice) and print its password_hash for a [[user]] in plant.toml",
    )
    p.set_defaults(func=_run)


def _hash_password() -> int:
    import getpass
    import sys

    from connectors.passwords import hash_password

    if sys.stdin.isatty():
        pw = getpass.getpass("password: ")
        if getpass.getpass("again: ") != pw:
            print("diag run: the passwords differ", file=sys.stderr)
            return 2
    else:
        pw = sys.stdin.readline().rstrip("\n")
    if len(pw) < 8:
        print("diag run: a password needs at least 8 characters", file=sys.stderr)
        return 2
    print(hash_password(pw))
    return 0


def _run(args: argparse.Namespace) -> int:
    import asyncio
    import sys

    if args.hash_password:
        return _hash_password()
    if args.check and not args.config:
        print("diag run: --check needs --config plant.toml", file=sys.stderr)
        return 2
    if args.config:
        from diag_plugin.live.config import ConfigError, check_config, load_config, run_config

        try:
            cfg = load_config(args.config)
            if args.check:
                print(check_config(cfg))
                return 0
            return asyncio.run(
                run_config(cfg, duration=args.duration, tty=False if args.plain else None)
            )
        except ConfigError as exc:
            for line in str(exc).splitlines():
                print(f"diag run: {line}", file=sys.stderr)
            return 2
    if args.cycle <= 0:
        print("diag run: --cycle must be positive", file=sys.stderr)
        return 2
    if busy := _busy([args.plc_port, args.modbus_port, args.opcua_port]):
        print(f"diag run: {busy}", file=sys.stderr)
        return 3
    from diag_plugin.live.embedded import run_embedded

    return asyncio.run(
        run_embedded(
            args.data,
            cycle=args.cycle,
            duration=args.duration,
            plc_port=args.plc_port,
            modbus_port=args.modbus_port,
            opcua_port=args.opcua_port,
            flush_every=args.flush_every,
            tty=False if args.plain else None,
        )
    )


def _busy(ports) -> str | None:
    """Which of the ports the embedded plant serves on 127.0.0.1 another program holds."""
    from diag_plugin.live.config import port_busy

    for port in ports:
        if port and (why := port_busy("127.0.0.1", int(port))):
            return f"port {port} on 127.0.0.1 {why}: stop what holds it or choose another port"
    return None
