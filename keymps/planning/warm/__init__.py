"""The warm planner: a local process that keeps litellm imported between `keymps run`s.

`import litellm` costs seconds; a `keymps run` is a new process that would pay it again for
every plan. The warm planner imports it once and answers each plan request in a child process
forked for that request alone, with the caller's own key variables, over a Unix socket in a
folder only the user can open (docs/vlm.md, "The warm planner"; docs/security.md).

- place.py: where the socket is, and the checks of its folder and of the peer's user id;
- wire.py: the messages on the socket (length-prefixed JSON, never pickle);
- server.py: the process (`python -m keymps.planning.warm.server`);
- client.py: `keymps run`'s side (the `dispatch` of a run) and `keymps planner start|stop|status`.
"""
