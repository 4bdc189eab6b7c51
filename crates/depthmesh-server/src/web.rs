//! The browser view's pages and files, embedded in the binary (nothing is
//! fetched at run time): `/` lists the sessions, `/view/NAME` shows one;
//! `/ws/view/NAME` is the view's WebSocket. The pages hold no data, so they
//! are served to anyone; everything they then ask for needs the token.

use crate::server::{request_token, Shared, TokenQuery};
use crate::view::socket;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{Path as UrlPath, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use std::sync::Arc;

/// The page, for both the list and a session's view.
const INDEX: &str = include_str!("../web/index.html");

/// The files the page loads: name, content type, bytes.
const ASSETS: [(&str, &str, &[u8]); 3] = [
    (
        "app.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../web/app.js"),
    ),
    (
        "style.css",
        "text/css; charset=utf-8",
        include_bytes!("../web/style.css"),
    ),
    (
        "vendor.min.js",
        "text/javascript; charset=utf-8",
        include_bytes!("../web/vendor/vendor.min.js"),
    ),
];

/// `/` and `/view/NAME`: the page.
pub async fn page() -> Response {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], INDEX).into_response()
}

/// `/assets/FILE`.
pub async fn asset(UrlPath(file): UrlPath<String>) -> Response {
    match ASSETS.iter().find(|(name, _, _)| *name == file) {
        Some((_, kind, bytes)) => (
            [
                (header::CONTENT_TYPE, *kind),
                (header::CACHE_CONTROL, "no-cache"),
            ],
            *bytes,
        )
            .into_response(),
        None => StatusCode::NOT_FOUND.into_response(),
    }
}

/// `/ws/view/NAME?token=T`: a viewer of session NAME, live or finished.
pub async fn view_socket(
    State(shared): State<Arc<Shared>>,
    UrlPath(name): UrlPath<String>,
    headers: HeaderMap,
    Query(query): Query<TokenQuery>,
    ws: WebSocketUpgrade,
) -> Response {
    if !request_token(&headers, &query).is_some_and(|t| shared.authorised(&t)) {
        return crate::server::refuse(StatusCode::UNAUTHORIZED, "a valid token is required");
    }
    let found = {
        let sessions = shared.sessions.lock().expect("sessions lock");
        sessions
            .get(&name)
            .map(|e| (e.view.clone(), e.inbox.clone()))
    };
    let Some((hub, inbox)) = found else {
        return crate::server::refuse(StatusCode::NOT_FOUND, "no such session");
    };
    ws.on_upgrade(move |socket| socket::watch(socket, shared, hub, inbox))
}
