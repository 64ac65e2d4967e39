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
        help="plant.toml: units, Modbus/OPC UA sources, outputs (docs/live.md)",
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
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import asyncio
    import sys

    if args.config:
        from diag_plugin.live.config import ConfigError, load_config, run_config

        try:
            cfg = load_config(args.config)
        except ConfigError as exc:
            print(f"diag run: {exc}", file=sys.stderr)
            return 2
        if busy := _busy([cfg.modbus_port, cfg.opcua_port]):
            print(f"diag run: {busy}", file=sys.stderr)
            return 3
        return asyncio.run(
            run_config(cfg, duration=args.duration, tty=False if args.plain else None)
        )
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
    """Which of the ports the plug-in serves on 127.0.0.1 another program holds already."""
    import socket

    for port in ports:
        if not port:
            continue
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", int(port)))
            except OSError as exc:
                return (
                    f"port {port} on 127.0.0.1 is busy ({exc.strerror}): stop what holds it "
                    "or choose another port"
                )
    return None
