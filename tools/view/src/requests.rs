//! What Foxglove clients ask of the view. The server calls these handlers on its own (tokio)
//! threads, which must not block and cannot touch the bus (its ports belong to the view's
//! thread), so each call becomes a [`Request`] on a channel that the view's loop drains.

use std::sync::mpsc::Sender;

use foxglove::websocket::{
    AnyClient, Client, ClientChannel, GetParametersResponder, Parameter, ParameterHandler,
    ServerListener, SetParametersResponder,
};

use crate::messages::parse_setpoint;

/// A client's request, for the view's loop.
pub(crate) enum Request {
    /// `getParameters` (empty `names`: every parameter).
    GetParameters {
        names: Vec<String>,
        responder: GetParametersResponder,
    },
    /// `setParameters`.
    SetParameters {
        client: AnyClient,
        parameters: Vec<Parameter>,
        responder: SetParametersResponder,
    },
    /// Clients want updates of these parameters (the first subscriber of each).
    SubscribeParameters(Vec<String>),
    /// Nobody wants updates of these any more.
    UnsubscribeParameters(Vec<String>),
    /// A client advertised a channel to publish on.
    Advertise { client: Client, topic: String },
    /// A message a client published (already parsed).
    Publish {
        client: Client,
        topic: String,
        value: Result<f64, String>,
    },
}

/// The server's [`ServerListener`] and [`ParameterHandler`]: forwards to the loop.
pub(crate) struct Forward {
    tx: Sender<Request>,
}

impl Forward {
    pub(crate) fn new(tx: Sender<Request>) -> Self {
        Self { tx }
    }

    fn send(&self, r: Request) {
        // The loop gone means the view is stopping: nothing to answer.
        let _ = self.tx.send(r);
    }
}

impl ParameterHandler for Forward {
    fn get(
        &self,
        _client: AnyClient,
        names: Vec<String>,
        _request_id: Option<String>,
        responder: GetParametersResponder,
    ) {
        self.send(Request::GetParameters { names, responder });
    }

    fn set(
        &self,
        client: AnyClient,
        parameters: Vec<Parameter>,
        _request_id: Option<String>,
        responder: SetParametersResponder,
    ) {
        self.send(Request::SetParameters {
            client,
            parameters,
            responder,
        });
    }
}

impl ServerListener for Forward {
    fn on_parameters_subscribe(&self, names: Vec<String>) {
        self.send(Request::SubscribeParameters(names));
    }

    fn on_parameters_unsubscribe(&self, names: Vec<String>) {
        self.send(Request::UnsubscribeParameters(names));
    }

    fn on_client_advertise(&self, client: Client, channel: &ClientChannel) {
        self.send(Request::Advertise {
            client,
            topic: channel.topic.clone(),
        });
    }

    fn on_message_data(&self, client: Client, channel: &ClientChannel, payload: &[u8]) {
        let value = if channel.encoding == crate::messages::MESSAGE_ENCODING {
            parse_setpoint(payload)
        } else {
            Err(format!(
                "encoding {:?} is not taken; publish JSON {{\"value\": <number>}}",
                channel.encoding
            ))
        };
        self.send(Request::Publish {
            client,
            topic: channel.topic.clone(),
            value,
        });
    }
}
