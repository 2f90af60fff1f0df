"""The Modbus layer: frames, upstream servers, downstream buses, serial lines, TLS."""
