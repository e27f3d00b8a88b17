"""JSON-RPC 2.0 over the daemon's Unix socket: the protocol both sides share, and the client."""
