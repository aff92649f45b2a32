"""One run's iceoryx2 domain and the loop's ports, as shared/transport opens them.

The prefix, the root path and the node settings are those of
shared/transport's ``Domain::new``; every service is opened with the QoS of
shared/protocol's channels, read from ``wire.json`` (iceoryx2 refuses to open
a service with other settings). An :class:`Outlet` is a publisher with a
notifier, an :class:`Inlet` a subscriber with, unless it polls, a listener.
"""

import ctypes

import iceoryx2 as iox

from . import messages

#: Where iceoryx2 keeps its files: on tmpfs (shared/transport domain.rs, ROOT_PATH).
ROOT_PATH = "/dev/shm/iceoryx2/"


class TransportError(Exception):
    """An iceoryx2 operation on a channel failed: says which and why."""

    def __init__(self, what, action, error):
        super().__init__(f"{what}: cannot {action}: {error!r}")


_WIRE = messages.wire_description()
CHANNELS = {c["name"]: c for c in _WIRE["channels"]}
EVENTS = _WIRE["events"]


class Domain:
    """The iceoryx2 configuration of one run, isolated by its prefix."""

    def __init__(self, prefix):
        # Quiet iceoryx2's own info lines unless IOX2_LOG_LEVEL asks for them.
        iox.set_log_level_from_env_or(iox.LogLevel.Error)
        self.prefix = prefix
        config = iox.config.default()
        try:
            config.global_cfg.prefix = iox.FileName.new(prefix)
        except Exception as e:
            raise TransportError(prefix, "use as iceoryx2 prefix", e) from e
        config.global_cfg.root_path = iox.Path.new(ROOT_PATH)
        # Dead nodes are the supervisor's to clean, never a loop process's
        # (shared/transport domain.rs says why).
        config.global_cfg.node.cleanup_dead_nodes_on_creation = False
        config.global_cfg.node.cleanup_dead_nodes_on_destruction = False
        self.config = config

    def node(self, name):
        """A node named ``name``; signals stay with the process."""
        try:
            return (
                iox.NodeBuilder.new()
                .name(iox.NodeName.new(name))
                .config(self.config)
                .signal_handling_mode(iox.SignalHandlingMode.Disabled)
                .create(iox.ServiceType.Ipc)
            )
        except Exception as e:
            raise TransportError(name, "create node", e) from e


def _service_name(channel):
    return iox.ServiceName.new(channel["name"])


def open_pubsub(node, channel, payload):
    """The channel's publish-subscribe service of ``payload``, as Rust opens it."""
    try:
        return (
            node.service_builder(_service_name(channel))
            .publish_subscribe(payload)
            .max_publishers(channel["max_publishers"])
            .max_subscribers(channel["max_subscribers"])
            .max_nodes(channel["max_nodes"])
            .history_size(channel["history_size"])
            .subscriber_max_buffer_size(channel["subscriber_max_buffer_size"])
            .subscriber_max_borrowed_samples(2)
            .enable_safe_overflow(True)
            .open_or_create()
        )
    except Exception as e:
        raise TransportError(channel["name"], "open publish-subscribe service", e) from e


def open_event(node, channel):
    """The channel's event service, as Rust opens it."""
    try:
        return (
            node.service_builder(_service_name(channel))
            .event()
            .max_notifiers(channel["max_publishers"])
            .max_listeners(channel["max_subscribers"])
            .max_nodes(channel["max_nodes"])
            .event_id_max_value(EVENTS["MAX_EVENT_ID"])
            .notifier_dead_event(iox.EventId.new(EVENTS["PUBLISHER_DEAD"]))
            .open_or_create()
        )
    except Exception as e:
        raise TransportError(channel["name"], "open event service", e) from e


def channel(name):
    """shared/protocol's channel ``name`` (``flexloop/measurement``, ...)."""
    return CHANNELS[name]


class Outlet:
    """Publishes samples of one message type on a channel and wakes its listeners."""

    def __init__(self, node, channel, payload):
        self.name = channel["name"]
        self.payload = payload
        self.size = ctypes.sizeof(payload)
        self.service = open_pubsub(node, channel, payload)
        try:
            self.publisher = self.service.publisher_builder().max_loaned_samples(2).create()
            self.notifier = (
                open_event(node, channel)
                .notifier_builder()
                .default_event_id(iox.EventId.new(EVENTS["SAMPLE"]))
                .create()
            )
        except TransportError:
            raise
        except Exception as e:
            raise TransportError(self.name, "create publisher and notifier", e) from e
        # The binding's own loan and assume_init (iceoryx2 0.10.0, pinned)
        # without its Python wrappers' type checks, which cost about 4 µs a
        # message in typing.get_origin (profiled); the payload type was
        # checked once, when the service was opened.
        self._loan = getattr(self.publisher, "__loan_uninit")

    def publish(self, message):
        """Sends a copy of ``message`` (a preallocated structure of the payload type)."""
        sample = self._loan()
        ctypes.memmove(sample.payload_ptr, ctypes.addressof(message), self.size)
        getattr(sample, "__assume_init")().send()

    def notify(self):
        self.notifier.notify()

    def subscribers(self):
        return self.service.dynamic_config.number_of_subscribers

    def connect(self):
        """Connects to every subscriber there now, so the first send does not pay for it."""
        self.publisher.update_connections()

    def close(self):
        self.notifier.delete()
        self.publisher.delete()


class Inlet:
    """Receives samples of one message type from a channel."""

    def __init__(self, node, channel, payload, buffer_size, listen=True, woken_by=None):
        """``listen``: with a listener on the channel's own event service
        (or, with ``woken_by``, on that channel's: a reader the publisher
        wakes at another moment, as the observer is); without, it polls."""
        self.name = channel["name"]
        self.payload = payload
        self.size = ctypes.sizeof(payload)
        self.service = open_pubsub(node, channel, payload)
        events = woken_by if woken_by is not None else channel
        try:
            self.subscriber = self.service.subscriber_builder().buffer_size(buffer_size).create()
            self.listener = (
                open_event(node, events).listener_builder().create()
                if listen or woken_by is not None
                else None
            )
        except TransportError:
            raise
        except Exception as e:
            raise TransportError(self.name, "create subscriber", e) from e

    def receive_into(self, message):
        """Copies the oldest queued sample into ``message`` and releases it
        at once (a subscriber may hold only two); False when none is queued."""
        sample = self.subscriber.receive()
        if sample is None:
            return False
        ctypes.memmove(ctypes.addressof(message), sample.payload_ptr, self.size)
        sample.delete()
        return True

    def has_samples(self):
        return self.subscriber.has_samples()

    def wait(self, timeout_s):
        """Waits at most ``timeout_s`` for a notification and consumes every
        pending one (so the notifier's socket never fills)."""
        self.listener.timed_wait(iox.Duration.from_secs_f64(timeout_s))

    def clear_events(self):
        if self.listener is not None:
            self.listener.try_wait()

    def publishers(self):
        return self.service.dynamic_config.number_of_publishers

    def close(self):
        if self.listener is not None:
            self.listener.delete()
        self.subscriber.delete()
