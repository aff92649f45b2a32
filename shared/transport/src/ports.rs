//! Outlets (publisher + notifier) and inlets (subscriber + listener).

use crate::TransportError;
use flexloop_protocol::channels::{Channel, events};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use std::fmt::Debug;
use std::os::fd::RawFd;

type PubSubFactory<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>;
type EventFactory = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;

fn open_pubsub<T>(
    node: &Node<ipc::Service>,
    channel: &Channel,
) -> Result<PubSubFactory<T>, TransportError>
where
    T: Debug + ZeroCopySend + 'static,
{
    let name: ServiceName = channel
        .name
        .try_into()
        .map_err(|e| TransportError::new(channel.name, "use as service name", e))?;
    let q = &channel.qos;
    node.service_builder(&name)
        .publish_subscribe::<T>()
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .max_nodes(q.max_nodes)
        .history_size(q.history_size)
        .subscriber_max_buffer_size(q.subscriber_max_buffer_size)
        .subscriber_max_borrowed_samples(2)
        // A slow reader loses its oldest samples; a publisher never blocks.
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(|e| TransportError::new(channel.name, "open publish-subscribe service", e))
}

fn open_event(
    node: &Node<ipc::Service>,
    channel: &Channel,
) -> Result<EventFactory, TransportError> {
    let name: ServiceName = channel
        .name
        .try_into()
        .map_err(|e| TransportError::new(channel.name, "use as service name", e))?;
    let q = &channel.qos;
    node.service_builder(&name)
        .event()
        .max_notifiers(q.max_publishers)
        .max_listeners(q.max_subscribers)
        .max_nodes(q.max_nodes)
        .event_id_max_value(events::MAX_EVENT_ID)
        .notifier_dead_event(EventId::new(events::PUBLISHER_DEAD))
        .open_or_create()
        .map_err(|e| TransportError::new(channel.name, "open event service", e))
}

/// A channel's services kept in existence without a port. The supervisor
/// holds every loop channel from before its first process starts, so that
/// the processes only ever open services: a process killed while it created
/// one would leave it half-made, and iceoryx2 0.10 refuses to open such a
/// service (`HangsInCreation`) for the rest of the run (seen when a test
/// killed a controller at start-up; fixed upstream after 0.10, iceoryx2
/// #1584). Holding a service adds no publisher or subscriber, so the
/// processes' own counts of their readers are unchanged.
pub struct ChannelHold {
    _samples: Option<Box<dyn std::any::Any>>,
    _events: EventFactory,
}

impl ChannelHold {
    /// The channel's publish–subscribe service of `T` and its event service.
    pub fn with_samples<T: Debug + ZeroCopySend + 'static>(
        node: &Node<ipc::Service>,
        channel: &'static Channel,
    ) -> Result<Self, TransportError> {
        let samples: Box<dyn std::any::Any> = Box::new(open_pubsub::<T>(node, channel)?);
        Ok(Self {
            _samples: Some(samples),
            _events: open_event(node, channel)?,
        })
    }

    /// The channel's event service alone (a [`Wakeup`] channel).
    pub fn events(
        node: &Node<ipc::Service>,
        channel: &'static Channel,
    ) -> Result<Self, TransportError> {
        Ok(Self {
            _samples: None,
            _events: open_event(node, channel)?,
        })
    }
}

/// Publishes samples of `T` on a channel and wakes its listeners.
pub struct Outlet<T: Debug + ZeroCopySend + 'static> {
    channel: &'static str,
    service: PubSubFactory<T>,
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
}

impl<T: Debug + Default + ZeroCopySend + 'static> Outlet<T> {
    pub fn open(
        node: &Node<ipc::Service>,
        channel: &'static Channel,
    ) -> Result<Self, TransportError> {
        let service = open_pubsub::<T>(node, channel)?;
        let publisher = service
            .publisher_builder()
            .max_loaned_samples(2)
            .create()
            .map_err(|e| TransportError::new(channel.name, "create publisher", e))?;
        let notifier = open_event(node, channel)?
            .notifier_builder()
            .default_event_id(EventId::new(events::SAMPLE))
            .create()
            .map_err(|e| TransportError::new(channel.name, "create notifier", e))?;
        Ok(Self {
            channel: channel.name,
            service,
            publisher,
            notifier,
        })
    }

    /// Loans a sample in shared memory, lets `fill` write it in place, sends it.
    /// Returns how many subscribers it reached.
    pub fn publish(&self, fill: impl FnOnce(&mut T)) -> Result<usize, TransportError> {
        let mut sample = self
            .publisher
            .loan()
            .map_err(|e| TransportError::new(self.channel, "loan", e))?;
        fill(sample.payload_mut());
        sample
            .send()
            .map_err(|e| TransportError::new(self.channel, "send", e))
    }

    /// Wakes every listener of the channel.
    pub fn notify(&self) -> Result<usize, TransportError> {
        self.notifier
            .notify()
            .map_err(|e| TransportError::new(self.channel, "notify", e))
    }

    /// Subscribers currently connected (for start-up synchronisation).
    pub fn subscribers(&self) -> usize {
        self.service.dynamic_config().number_of_subscribers()
    }

    /// Connects to every subscriber present now, so that the first publish in
    /// the loop does not pay for it.
    pub fn connect(&self) -> Result<(), TransportError> {
        self.publisher
            .update_connections()
            .map_err(|e| TransportError::new(self.channel, "connect to subscribers", e))
    }
}

/// A second wake-up for the readers of a channel, so that a publisher wakes
/// them in the order it chooses (the one on the critical path first).
pub struct Wakeup {
    channel: &'static str,
    notifier: Notifier<ipc::Service>,
}

impl Wakeup {
    pub fn open(
        node: &Node<ipc::Service>,
        wakeup: &'static Channel,
    ) -> Result<Self, TransportError> {
        let notifier = open_event(node, wakeup)?
            .notifier_builder()
            .default_event_id(EventId::new(events::SAMPLE))
            .create()
            .map_err(|e| TransportError::new(wakeup.name, "create notifier", e))?;
        Ok(Self {
            channel: wakeup.name,
            notifier,
        })
    }

    pub fn wake(&self) -> Result<usize, TransportError> {
        self.notifier
            .notify()
            .map_err(|e| TransportError::new(self.channel, "notify", e))
    }
}

/// The listening end of a [`Wakeup`] channel: an event without samples,
/// for a reader that only needs to know that something happened (the
/// supervisor, woken by the plant's silence alarm).
pub struct WakeupListener {
    channel: &'static str,
    listener: Listener<ipc::Service>,
}

impl WakeupListener {
    pub fn open(
        node: &Node<ipc::Service>,
        wakeup: &'static Channel,
    ) -> Result<Self, TransportError> {
        let listener = open_event(node, wakeup)?
            .listener_builder()
            .create()
            .map_err(|e| TransportError::new(wakeup.name, "create listener", e))?;
        Ok(Self {
            channel: wakeup.name,
            listener,
        })
    }

    /// Readable while a wake-up is pending.
    pub fn fd(&self) -> RawFd {
        // SAFETY: the descriptor stays owned by the listener; we only poll it.
        unsafe { self.listener.file_descriptor().native_handle() }
    }

    /// Consumes the pending wake-ups; returns whether there were any.
    pub fn clear(&self) -> Result<bool, TransportError> {
        self.listener
            .try_wait(|_| {})
            .map(|n| n > 0)
            .map_err(|e| TransportError::new(self.channel, "read events", e))
    }
}

/// Receives samples of `T` from a channel; its listener's fd signals arrivals.
pub struct Inlet<T: Debug + ZeroCopySend + 'static> {
    channel: &'static str,
    service: PubSubFactory<T>,
    subscriber: Subscriber<ipc::Service, T, ()>,
    /// Absent for a polling reader (the logger): notifiers then never wake it.
    listener: Option<Listener<ipc::Service>>,
}

impl<T: Debug + ZeroCopySend + 'static> Inlet<T> {
    /// `buffer_size` samples are queued before the oldest is overwritten.
    pub fn open(
        node: &Node<ipc::Service>,
        channel: &'static Channel,
        buffer_size: usize,
    ) -> Result<Self, TransportError> {
        Self::open_with(node, channel, buffer_size, true)
    }

    /// An inlet woken by another channel's event service than its own: a
    /// reader the publisher wakes at a different moment (see [`Wakeup`]).
    pub fn open_woken_by(
        node: &Node<ipc::Service>,
        channel: &'static Channel,
        wakeup: &'static Channel,
        buffer_size: usize,
    ) -> Result<Self, TransportError> {
        let mut inlet = Self::open_with(node, channel, buffer_size, false)?;
        inlet.listener = Some(
            open_event(node, wakeup)?
                .listener_builder()
                .create()
                .map_err(|e| TransportError::new(wakeup.name, "create listener", e))?,
        );
        Ok(inlet)
    }

    /// An inlet without a listener, for a reader that polls on its own clock.
    pub fn open_polling(
        node: &Node<ipc::Service>,
        channel: &'static Channel,
        buffer_size: usize,
    ) -> Result<Self, TransportError> {
        Self::open_with(node, channel, buffer_size, false)
    }

    fn open_with(
        node: &Node<ipc::Service>,
        channel: &'static Channel,
        buffer_size: usize,
        with_listener: bool,
    ) -> Result<Self, TransportError> {
        let service = open_pubsub::<T>(node, channel)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(buffer_size)
            .create()
            .map_err(|e| TransportError::new(channel.name, "create subscriber", e))?;
        let listener = if with_listener {
            Some(
                open_event(node, channel)?
                    .listener_builder()
                    .create()
                    .map_err(|e| TransportError::new(channel.name, "create listener", e))?,
            )
        } else {
            None
        };
        Ok(Self {
            channel: channel.name,
            service,
            subscriber,
            listener,
        })
    }

    /// The listener's descriptor, readable when a notification is pending
    /// (-1 for a polling inlet, which `ppoll` ignores).
    pub fn fd(&self) -> RawFd {
        match &self.listener {
            // SAFETY: the descriptor stays owned by the listener; we only poll it.
            Some(listener) => unsafe { listener.file_descriptor().native_handle() },
            None => -1,
        }
    }

    /// Consumes pending notifications so the fd is quiet again and the
    /// notifier's socket never fills.
    pub fn clear_events(&self) -> Result<(), TransportError> {
        match &self.listener {
            Some(listener) => listener
                .try_wait(|_| {})
                .map(|_| ())
                .map_err(|e| TransportError::new(self.channel, "read events", e)),
            None => Ok(()),
        }
    }

    /// The next queued sample, oldest first.
    pub fn receive(&self) -> Result<Option<Sample<ipc::Service, T, ()>>, TransportError> {
        self.subscriber
            .receive()
            .map_err(|e| TransportError::new(self.channel, "receive", e))
    }

    /// Whether a sample is queued (for a process that spins instead of
    /// waiting for the event).
    pub fn has_samples(&self) -> Result<bool, TransportError> {
        self.subscriber
            .has_samples()
            .map_err(|e| TransportError::new(self.channel, "poll", e))
    }

    /// Publishers currently connected.
    pub fn publishers(&self) -> usize {
        self.service.dynamic_config().number_of_publishers()
    }

    /// Maps the memory of every publisher present now. Under `mlockall` a
    /// mapping is populated page by page in the kernel; done on the first
    /// `receive` inside the loop it stalls the whole CPU for milliseconds.
    pub fn connect(&self) -> Result<(), TransportError> {
        self.subscriber
            .update_connections()
            .map_err(|e| TransportError::new(self.channel, "connect to publishers", e))
    }
}
