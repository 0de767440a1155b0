//! The web dashboard that `serve` gives at `/`: plain HTML, CSS and a little JavaScript, built
//! into the binary (no CDN, no build step; it works with no network). It calls the API like any
//! client, with a token when the service takes tokens; the pages themselves hold no data and
//! stay open.

use axum::http::header;
use axum::response::IntoResponse;
use axum::routing::get;

const INDEX: &str = include_str!("dashboard/index.html");
const SCRIPT: &str = include_str!("dashboard/app.js");
const STYLE: &str = include_str!("dashboard/style.css");

/// The paths the dashboard serves, open without a token.
pub fn is_dashboard(path: &str) -> bool {
    matches!(path, "/" | "/dashboard/app.js" | "/dashboard/style.css")
}

pub fn routes<S: Clone + Send + Sync + 'static>() -> axum::Router<S> {
    let page = |content_type: &'static str, body: &'static str| {
        get(move || async move { ([(header::CONTENT_TYPE, content_type)], body).into_response() })
    };
    axum::Router::new()
        .route("/", page("text/html; charset=utf-8", INDEX))
        .route("/dashboard/app.js", page("text/javascript; charset=utf-8", SCRIPT))
        .route("/dashboard/style.css", page("text/css; charset=utf-8", STYLE))
}
