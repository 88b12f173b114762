"""The runtime: the only package with threads and network I/O (paho only in `runtime.mqtt`).

`core` (pure) says what every MQTT unit's core looks like; `unit` runs a core on a broker;
`commands` remembers answers per com-uuid; `broker` starts local brokers; `client` is the
operator-side client of the delegation service.
"""
