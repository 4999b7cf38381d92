"""Subcommands of `okid-ros`, one module each.

To add a command `NAME`:

1. create `okid_ros/commands/NAME.py` with
   - `add_parser(subparsers) -> argparse.ArgumentParser`: registers the subparser with
     `subparsers.add_parser(...)` and calls `set_defaults(func=run)`;
   - `run(args: argparse.Namespace) -> int`: does the work and returns the exit status;
     raises `okid_ros.errors.OkidError` (or a subclass) for failures the user can fix;
2. add `"okid_ros.commands.NAME"` to `COMMAND_MODULES` in `okid_ros/cli.py`.

Every command module is imported to build the parser, also for `okid-ros --help`: keep its
top level light and import rclpy, scipy, matplotlib and the like inside `run`.
"""
