"""Publishing every poll to an MQTT broker: frame payloads (``payload``), the publisher that
runs beside the poll loop (``publisher``) and its Prometheus counters (``collector``).
``docs/mqtt.md`` documents topics and payloads."""
