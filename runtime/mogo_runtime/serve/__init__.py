"""The motion server: a crowd hosted for WebSocket clients that receive token streams (server.py, protocol.py),
its client (client.py), `mogo serve` (command.py) and its Ray Serve deployment (ray.py). Needs the `serve` extra
(websockets), imported only by what uses it."""
