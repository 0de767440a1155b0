//! The HTTP API (axum). Every error is JSON: `{"error":{"code":"...","message":"..."}}`.

use super::auth::{Scope, Tokens};
use super::{Service, SubmitError, Submitted};
use crate::config::{self, ConfigError};
use crate::key::cache_key;
use crate::level::{InstanceSpec, Level, Manifest, MeshRef, is_key, parse_manifest};
use crate::mesh::{Format, load_bytes};
use crate::store::job::{Job, JobError};
use crate::store::{Input, Unwritten};
use axum::Json;
use axum::body::Body;
use axum::extract::multipart::{Multipart, MultipartError, MultipartRejection};
use axum::extract::{DefaultBodyLimit, Path, Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use futures_util::stream::{self, Stream};
use metrics_exporter_prometheus::PrometheusHandle;
use serde::Serialize;
use std::collections::HashMap;
use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;
use utoipa::{OpenApi, ToSchema};

#[derive(Clone)]
pub struct AppState {
    pub service: Arc<Service>,
    pub metrics: PrometheusHandle,
    /// Turns true on shutdown, ending event streams.
    pub shutdown: watch::Receiver<bool>,
    /// With `service.auth = "tokens"`, the tokens that may call.
    pub tokens: Option<Arc<Tokens>>,
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "occluder-cook",
        description = "Conservative occluders for game meshes, cooked and cached by content key."
    ),
    paths(
        submit_cook,
        submit_level,
        job_status,
        cancel_job,
        job_events,
        occluder_glb,
        occluder_report,
        occluder_preview,
        level_preview,
        recent_jobs,
        activity,
        healthz,
        metrics_text
    ),
    components(schemas(
        Accepted,
        ErrorBody,
        ErrorDetail,
        Job,
        JobError,
        JobList,
        super::Activity,
        crate::store::job::JobState,
        crate::store::job::JobKind
    )),
    modifiers(&BearerTokens)
)]
pub struct ApiDoc;

/// The bearer tokens of `service.auth = "tokens"`, as the document's security scheme.
struct BearerTokens;

impl utoipa::Modify for BearerTokens {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
        let scheme = HttpBuilder::new()
            .scheme(HttpAuthScheme::Bearer)
            .description(Some(
                "With service.auth = \"tokens\": a token with the scope the endpoint needs (read: GET; cook: POST; admin: /metrics). /healthz is open.",
            ))
            .build();
        openapi
            .components
            .get_or_insert_with(Default::default)
            .add_security_scheme("bearer", SecurityScheme::Http(scheme));
    }
}

pub fn router(state: AppState) -> axum::Router {
    axum::Router::new()
        .route("/v1/cook", post(submit_cook))
        .route(
            "/v1/levels",
            post(submit_level).layer(DefaultBodyLimit::max(state.service.settings.service.max_body_bytes)),
        )
        .route("/v1/jobs", get(recent_jobs))
        .route("/v1/activity", get(activity))
        .route("/v1/jobs/{id}", get(job_status).delete(cancel_job))
        .route("/v1/jobs/{id}/events", get(job_events))
        .route("/v1/occluders/{key}", get(occluder_glb))
        .route("/v1/occluders/{key}/report", get(occluder_report))
        .route("/v1/occluders/{key}/preview.png", get(occluder_preview))
        .route("/v1/levels/{key}/preview.png", get(level_preview))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics_text))
        .route("/openapi.json", get(openapi_json))
        .merge(super::dashboard::routes())
        .fallback(|| async { ApiError::new(StatusCode::NOT_FOUND, "not_found", "no such route") })
        .method_not_allowed_fallback(|| async {
            ApiError::new(
                StatusCode::METHOD_NOT_ALLOWED,
                "method_not_allowed",
                "method not allowed here",
            )
        })
        .layer(axum::middleware::from_fn_with_state(state.clone(), authorize))
        .with_state(state)
}

/// The scopes that may make a request, any one of them; none for what stays open.
fn scopes_for(method: &axum::http::Method, path: &str) -> &'static [Scope] {
    use axum::http::Method;
    match path {
        "/healthz" => &[],
        _ if super::dashboard::is_dashboard(path) && method == Method::GET => &[],
        "/metrics" => &[Scope::Admin],
        _ if method == Method::POST => &[Scope::Cook],
        // Cancelling: its own jobs with `cook`, any with `admin`.
        _ if method == Method::DELETE => &[Scope::Cook, Scope::Admin],
        _ => &[Scope::Read],
    }
}

/// The name of the token that files a job, when the service takes tokens.
fn owner_of(caller: &Option<axum::Extension<Caller>>) -> Option<String> {
    caller.as_ref().map(|axum::Extension(Caller(entry))| entry.name.clone())
}

/// The token a request came with, once let through.
#[derive(Clone)]
struct Caller(super::auth::Entry);

/// With tokens on, lets a request through only with a known bearer token that has the scope its
/// endpoint needs: 401 without one, 403 with the wrong scope.
async fn authorize(
    State(state): State<AppState>,
    mut request: axum::extract::Request,
    next: axum::middleware::Next,
) -> Response {
    let Some(tokens) = &state.tokens else {
        return next.run(request).await;
    };
    let needed = scopes_for(request.method(), request.uri().path());
    if needed.is_empty() {
        return next.run(request).await;
    }
    let bearer = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "));
    let refused = match bearer.map(|token| tokens.check(token.trim())) {
        None => ApiError::new(
            StatusCode::UNAUTHORIZED,
            "unauthorized",
            "this endpoint needs a token: Authorization: Bearer <token>",
        ),
        Some(None) => ApiError::new(StatusCode::UNAUTHORIZED, "unauthorized", "the token is not known"),
        Some(Some(entry)) if !needed.iter().any(|scope| entry.scopes.contains(scope)) => ApiError::new(
            StatusCode::FORBIDDEN,
            "forbidden",
            format!("token `{}` lacks the `{}` scope", entry.name, needed[0].name()),
        ),
        Some(Some(entry)) if request.method() == axum::http::Method::POST => {
            metrics::counter!("occluder_submissions_total", "token" => entry.name.clone()).increment(1);
            match tokens.take_submission(&entry.name) {
                Ok(()) => {
                    request.extensions_mut().insert(Caller(entry));
                    return next.run(request).await;
                }
                Err(wait_s) => {
                    metrics::counter!("occluder_submissions_limited_total", "token" => entry.name.clone()).increment(1);
                    ApiError {
                        retry_after: Some(wait_s.ceil().max(1.0) as u64),
                        ..ApiError::new(
                            StatusCode::TOO_MANY_REQUESTS,
                            "rate_limited",
                            format!("token `{}` is over service.token_submissions_per_s", entry.name),
                        )
                    }
                }
            }
        }
        Some(Some(entry)) => {
            request.extensions_mut().insert(Caller(entry));
            return next.run(request).await;
        }
    };
    let mut response = refused.into_response();
    if response.status() == StatusCode::UNAUTHORIZED {
        response
            .headers_mut()
            .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
    }
    response
}

/// The answer to a submission.
#[derive(Serialize, ToSchema)]
pub struct Accepted {
    /// The job that makes (or made) the result.
    pub job: String,
    pub key: String,
    pub status_url: String,
    pub result_url: String,
}

#[derive(Serialize, ToSchema)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Serialize, ToSchema)]
pub struct ErrorDetail {
    pub code: String,
    pub message: String,
}

#[derive(Debug)]
pub struct ApiError {
    status: StatusCode,
    code: &'static str,
    message: String,
    retry_after: Option<u64>,
}

impl ApiError {
    fn new(status: StatusCode, code: &'static str, message: impl Into<String>) -> ApiError {
        ApiError {
            status,
            code,
            message: message.into(),
            retry_after: None,
        }
    }

    fn storage(e: impl std::fmt::Display) -> ApiError {
        tracing::error!(error = %e, "storage error");
        // Usually passing (a NATS server restarting): worth a retry.
        ApiError {
            retry_after: Some(1),
            ..ApiError::new(StatusCode::SERVICE_UNAVAILABLE, "storage", e.to_string())
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: ErrorDetail {
                code: self.code.into(),
                message: self.message,
            },
        };
        let mut response = (self.status, Json(body)).into_response();
        if let Some(seconds) = self.retry_after {
            response
                .headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(seconds));
        }
        response
    }
}

fn accepted(key: &str, job: String) -> Accepted {
    Accepted {
        status_url: format!("/v1/jobs/{job}"),
        result_url: format!("/v1/occluders/{key}"),
        key: key.to_string(),
        job,
    }
}

/// The mesh format from `?format=` or the Content-Type.
fn format_of(query: Option<&str>, headers: &HeaderMap) -> Result<Format, ApiError> {
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(|v| v.split(';').next().unwrap_or("").trim().to_ascii_lowercase());
    let name = match (query, content_type.as_deref()) {
        (Some(q), _) => q.to_ascii_lowercase(),
        (None, media) => match MEDIA_TYPES.iter().find(|(m, _)| Some(*m) == media) {
            Some((_, format)) => format.name().into(),
            None => {
                let known: Vec<&str> = MEDIA_TYPES.iter().map(|(m, _)| *m).collect();
                return Err(ApiError::new(
                    StatusCode::UNSUPPORTED_MEDIA_TYPE,
                    "unknown_format",
                    format!(
                        "Content-Type {} is not a mesh type: use ?format= or one of {}",
                        media.unwrap_or("(none)"),
                        known.join(", ")
                    ),
                ));
            }
        },
    };
    Format::from_name(&name).ok_or_else(|| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            "unknown_format",
            format!("format `{name}` is not one of glb, gltf, fbx, obj, ply, stl"),
        )
    })
}

/// The Content-Types a mesh upload may name instead of `?format=`. FBX and PLY have no
/// registered type: the common unregistered ones are taken.
const MEDIA_TYPES: [(&str, Format); 10] = [
    ("model/gltf-binary", Format::Gltf),
    ("model/gltf+json", Format::Gltf),
    ("model/vnd.fbx", Format::Fbx),
    ("application/vnd.autodesk.fbx", Format::Fbx),
    ("model/obj", Format::Obj),
    ("model/x-ply", Format::Ply),
    ("application/ply", Format::Ply),
    ("model/stl", Format::Stl),
    ("model/x.stl-binary", Format::Stl),
    ("model/x.stl-ascii", Format::Stl),
];

/// The server's settings with the query's overrides of the `sections` given (a bare name means
/// `cook.NAME`).
fn job_settings(
    service: &Service,
    params: &[(String, String)],
    sections: &[&str],
) -> Result<config::Settings, ApiError> {
    let bad = |e: ConfigError| ApiError::new(StatusCode::BAD_REQUEST, "bad_settings", e.to_string());
    let mut overrides = Vec::new();
    for (key, value) in params.iter().filter(|(k, _)| k != "format") {
        let key = if key.contains('.') {
            key.clone()
        } else {
            format!("cook.{key}")
        };
        let section = key.split('.').next().unwrap_or_default();
        if key == "cook.max_placed_triangles" {
            return Err(ApiError::new(
                StatusCode::BAD_REQUEST,
                "bad_settings",
                format!("setting `{key}` is the server's limit: it cannot be set per job"),
            ));
        }
        if !sections.contains(&section) {
            let allowed: Vec<String> = sections.iter().map(|s| format!("{s}.*")).collect();
            return Err(ApiError::new(
                StatusCode::BAD_REQUEST,
                "bad_settings",
                format!(
                    "setting `{key}` cannot be set per job: only {} settings can",
                    allowed.join(" and ")
                ),
            ));
        }
        overrides.push(config::parse_assignment(&format!("{key}={value}")).map_err(bad)?);
    }
    let settings = match overrides.is_empty() {
        true => service.settings.clone(),
        false => config::load_over(&service.settings, &overrides).map_err(bad)?,
    };
    let caps = [
        (
            "cook.resolution",
            settings.cook.resolution,
            "service.max_resolution",
            service.settings.service.max_resolution,
        ),
        (
            "cook.quad_grid",
            settings.cook.quad_grid,
            "service.max_quad_grid",
            service.settings.service.max_quad_grid,
        ),
    ];
    if let Some((key, value, cap, limit)) = caps.into_iter().find(|(_, value, _, limit)| value > limit) {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "over_limit",
            format!("{key} = {value} is over this server's {cap} ({limit})"),
        ));
    }
    // A job that asks for a GPU this server lacks would only fail later.
    if settings.cook.device == crate::gpu::DeviceChoice::Gpu && crate::gpu::best_adapter_info().is_none() {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "no_gpu",
            "cook.device=gpu, but this server has no GPU adapter: use device=auto or device=cpu".to_string(),
        ));
    }
    Ok(settings)
}

#[utoipa::path(
    post, path = "/v1/cook",
    params(
        ("format" = Option<String>, Query, description = "glb, gltf, fbx, obj, ply or stl; else the Content-Type decides"),
    ),
    request_body(description = "The mesh file: glTF (GLB, or .gltf with embedded buffers), FBX (binary or ASCII), OBJ, PLY or STL",
        content(
            (Vec<u8> = "model/gltf-binary"), (Vec<u8> = "model/gltf+json"),
            (Vec<u8> = "model/vnd.fbx"), (Vec<u8> = "application/vnd.autodesk.fbx"),
            (Vec<u8> = "model/obj"), (Vec<u8> = "model/x-ply"), (Vec<u8> = "application/ply"),
            (Vec<u8> = "model/stl"), (Vec<u8> = "model/x.stl-binary"), (Vec<u8> = "model/x.stl-ascii"),
            (Vec<u8> = "application/octet-stream"),
        )
    ),
    responses(
        (status = 200, description = "Already cooked: the result is there", body = Accepted),
        (status = 202, description = "Queued (or already queued or running)", body = Accepted),
        (status = 400, description = "Bad settings", body = ErrorBody),
        (status = 413, description = "Body over service.max_body_bytes", body = ErrorBody),
        (status = 415, description = "Unknown mesh type", body = ErrorBody),
        (status = 422, description = "The mesh cannot be read, or device=gpu on a server without a GPU", body = ErrorBody),
        (status = 429, description = "The queue is full; see Retry-After", body = ErrorBody),
    )
)]
async fn submit_cook(
    State(state): State<AppState>,
    caller: Option<axum::Extension<Caller>>,
    Query(params): Query<Vec<(String, String)>>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let service = &state.service;
    let limit = service.settings.service.max_body_bytes;
    let too_large = || {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            "too_large",
            format!("the body is over service.max_body_bytes ({limit} bytes)"),
        )
    };
    let declared = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
    if declared.is_some_and(|n| n > limit as u64) {
        return Err(too_large());
    }
    let format_param = params.iter().find(|(k, _)| k == "format").map(|(_, v)| v.as_str());
    let format = format_of(format_param, &headers)?;
    let settings = job_settings(service, &params, &["cook"])?;
    let bytes = axum::body::to_bytes(body, limit).await.map_err(|_| too_large())?;
    if bytes.is_empty() {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "bad_mesh",
            "the body is empty",
        ));
    }
    let settings_json = serde_json::to_value(&settings.cook).expect("settings serialize");
    let mut upload = blake3::Hasher::new();
    upload.update(format.name().as_bytes());
    upload.update(settings_json.to_string().as_bytes());
    upload.update(&bytes);
    let upload = upload.finalize();
    let key = match service.seen_key(&upload) {
        Some(key) => key,
        None => {
            let cook_settings = settings.cook.clone();
            let limits = settings.ingest_limits();
            let parse = bytes.clone();
            let key = tokio::task::spawn_blocking(move || {
                let (mesh, _) = load_bytes(&parse, format, None, &limits)?;
                Ok::<_, crate::mesh::IngestError>(cache_key(&mesh, &cook_settings))
            })
            .await
            .map_err(|e| {
                ApiError::new(
                    StatusCode::UNPROCESSABLE_ENTITY,
                    "bad_mesh",
                    format!("reading the mesh crashed: {e}"),
                )
            })?
            .map_err(bad_mesh)?;
            service.remember_key(upload, &key);
            key
        }
    };
    let input = Input {
        format: format.name().into(),
        bytes: bytes.to_vec(),
    };
    submitted(
        &key,
        service.submit(&key, input, settings_json, owner_of(&caller)).await,
    )
}

/// An upload that does not read: 413 when reading it would take more than the server allows,
/// else 422.
fn bad_mesh(e: crate::mesh::IngestError) -> ApiError {
    match e {
        crate::mesh::IngestError::TooLarge(why) => ApiError::new(StatusCode::PAYLOAD_TOO_LARGE, "too_large", why),
        e => ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "bad_mesh", e.to_string()),
    }
}

fn bad_level(message: impl Into<String>) -> ApiError {
    ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "bad_level", message)
}

fn multipart_error(e: MultipartError) -> ApiError {
    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::new(StatusCode::PAYLOAD_TOO_LARGE, "too_large", e.body_text())
    } else {
        ApiError::new(StatusCode::BAD_REQUEST, "bad_multipart", e.body_text())
    }
}

#[utoipa::path(
    post, path = "/v1/levels",
    params(
        ("cook.*" = Option<String>, Query, description = "cook settings for the level's meshes"),
        ("level.*" = Option<String>, Query, description = "level settings (batch limits)"),
    ),
    request_body(
        content = Vec<u8>, content_type = "multipart/form-data",
        description = "A part `manifest` (the level's JSON manifest) and one part per uploaded mesh, \
            named as the manifest names it (or a part `mesh` whose file name is that name). \
            A manifest entry that names no part is the key of a mesh uploaded before."
    ),
    responses(
        (status = 200, description = "Already baked: the level's GLB is at result_url", body = Accepted),
        (status = 202, description = "Queued; the job's progress is at status_url", body = Accepted),
        (status = 400, description = "Not multipart, a part named twice or unused, or bad settings", body = ErrorBody),
        (status = 413, description = "Body over service.max_body_bytes", body = ErrorBody),
        (status = 422, description = "Bad manifest, mesh or transform, a mesh neither uploaded nor known, or device=gpu on a server without a GPU", body = ErrorBody),
        (status = 429, description = "The queue is full; see Retry-After", body = ErrorBody),
    )
)]
async fn submit_level(
    State(state): State<AppState>,
    caller: Option<axum::Extension<Caller>>,
    Query(params): Query<Vec<(String, String)>>,
    multipart: Result<Multipart, MultipartRejection>,
) -> Result<Response, ApiError> {
    let service = &state.service;
    let settings = job_settings(service, &params, &["cook", "level"])?;
    let multipart = multipart.map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, "bad_multipart", e.body_text()))?;
    let (manifest, parts) = read_level_parts(multipart).await?;
    let uploads = key_uploads(parts, settings.cook.clone(), settings.ingest_limits()).await?;
    let (key_of, filed) = file_level_meshes(service, &manifest, uploads).await?;
    let queued = queue_level(service, manifest, key_of, settings, owner_of(&caller)).await;
    if queued.is_err() {
        // Refused: nothing will cook the meshes just filed for it.
        for key in &filed {
            if let Err(e) = service.store.delete_input(key).await {
                tracing::warn!(key, error = %e, "cannot delete a refused level's mesh");
            }
        }
    }
    queued
}

/// Files the job of a level whose meshes are filed, under the key of its manifest (every mesh
/// as its key) and settings.
async fn queue_level(
    service: &Service,
    manifest: Manifest,
    key_of: HashMap<String, String>,
    settings: crate::config::Settings,
    owner: Option<String>,
) -> Result<Response, ApiError> {
    // Every mesh as its key: the level's input, and what its key is made of.
    let resolved = Manifest {
        name: manifest.name,
        source: manifest.source,
        instances: manifest
            .instances
            .into_iter()
            .map(|i| InstanceSpec {
                mesh: key_of
                    .get(&i.mesh)
                    .or_else(|| key_of.get(&i.mesh.to_ascii_lowercase()))
                    .cloned()
                    .unwrap_or(i.mesh),
                transform: i.transform,
            })
            .collect(),
    };
    let bytes = serde_json::to_vec(&resolved).expect("manifests serialize");
    Level::from_manifest(resolved, |mesh| {
        key_of
            .values()
            .any(|k| k == mesh)
            .then(|| MeshRef::Key(mesh.to_string()))
    })
    .map_err(|e| bad_level(e.to_string()))?;
    let settings_json = serde_json::to_value(super::LevelJobSettings {
        cook: settings.cook,
        level: settings.level,
    })
    .expect("settings serialize");
    let mut hasher = blake3::Hasher::new();
    hasher.update(b"level\n");
    hasher.update(settings_json.to_string().as_bytes());
    hasher.update(&bytes);
    let key = hasher.finalize().to_hex().to_string();
    let input = Input {
        format: super::LEVEL_FORMAT.into(),
        bytes,
    };
    submitted(&key, service.submit(&key, input, settings_json, owner).await)
}

/// A level upload's manifest and its mesh parts by name; every part must be used by an instance.
async fn read_level_parts(
    mut multipart: Multipart,
) -> Result<(Manifest, HashMap<String, axum::body::Bytes>), ApiError> {
    let bad_multipart = |message: String| ApiError::new(StatusCode::BAD_REQUEST, "bad_multipart", message);
    let mut manifest = None;
    let mut parts: HashMap<String, axum::body::Bytes> = HashMap::new();
    while let Some(field) = multipart.next_field().await.map_err(multipart_error)? {
        let name = match field.name().unwrap_or_default() {
            "mesh" => field.file_name().unwrap_or_default().to_string(),
            other => other.to_string(),
        };
        let bytes = field.bytes().await.map_err(multipart_error)?;
        if name == "manifest" {
            manifest = Some(bytes);
        } else if name.is_empty() {
            return Err(bad_multipart("a part has no name".into()));
        } else if parts.insert(name.clone(), bytes).is_some() {
            return Err(bad_multipart(format!("part `{name}` is sent twice")));
        }
    }
    let manifest = manifest.ok_or_else(|| bad_multipart("no `manifest` part".into()))?;
    let manifest = parse_manifest("manifest", &manifest).map_err(|e| bad_level(e.to_string()))?;
    if let Some(unused) = parts
        .keys()
        .find(|name| manifest.instances.iter().all(|i| &i.mesh != *name))
    {
        return Err(bad_multipart(format!("part `{unused}` is not used by any instance")));
    }
    Ok((manifest, parts))
}

/// Each uploaded mesh's (name, key, input), read and keyed in parallel, off the async threads.
async fn key_uploads(
    parts: HashMap<String, axum::body::Bytes>,
    cook: crate::config::CookSettings,
    limits: crate::mesh::IngestLimits,
) -> Result<Vec<(String, String, Input)>, ApiError> {
    use rayon::prelude::*;
    tokio::task::spawn_blocking(move || {
        parts
            .into_par_iter()
            .map(|(name, bytes)| {
                let bad = |why: String| bad_level(format!("part `{name}`: {why}"));
                let format = Format::from_extension(std::path::Path::new(&name)).map_err(|e| bad(e.to_string()))?;
                let (mesh, _) = load_bytes(&bytes, format, None, &limits).map_err(|e| bad(e.to_string()))?;
                let input = Input {
                    format: format.name().into(),
                    bytes: bytes.to_vec(),
                };
                Ok((name, cache_key(&mesh, &cook), input))
            })
            .collect::<Result<Vec<_>, ApiError>>()
    })
    .await
    .map_err(|e| bad_level(format!("reading a mesh crashed: {e}")))?
}

/// Files the uploads' inputs where their results are not cached, and maps each mesh name of the
/// manifest to its key: an upload's, or a key the store knows. Also returns the keys filed.
async fn file_level_meshes(
    service: &Service,
    manifest: &Manifest,
    uploads: Vec<(String, String, Input)>,
) -> Result<(HashMap<String, String>, Vec<String>), ApiError> {
    let mut key_of: HashMap<String, String> = HashMap::new();
    let mut filed = Vec::new();
    for (name, key, input) in uploads {
        if service.result_meta(&key).await.map_err(ApiError::storage)?.is_none() {
            service.store.put_input(&key, &input).await.map_err(ApiError::storage)?;
            filed.push(key.clone());
        }
        key_of.insert(name, key);
    }
    for spec in &manifest.instances {
        let mesh = spec.mesh.to_ascii_lowercase();
        if key_of.contains_key(&spec.mesh) || !is_key(&mesh) || key_of.contains_key(&mesh) {
            continue;
        }
        let known = service.result_meta(&mesh).await.map_err(ApiError::storage)?.is_some()
            || service.store.input(&mesh).await.map_err(ApiError::storage)?.is_some();
        if known {
            key_of.insert(mesh.clone(), mesh);
        }
    }
    Ok((key_of, filed))
}

/// 200 with a done job of a cached result (see [`Service::submit`]), 202 with `Location` for a
/// queued one.
fn submitted(key: &str, outcome: Result<Submitted, SubmitError>) -> Result<Response, ApiError> {
    match outcome {
        Ok(Submitted::Cached(job)) => Ok((StatusCode::OK, Json(accepted(key, job))).into_response()),
        Ok(Submitted::Queued(job)) => {
            let body = accepted(key, job);
            let location = HeaderValue::from_str(&body.status_url).expect("ids are ASCII");
            Ok((StatusCode::ACCEPTED, [(header::LOCATION, location)], Json(body)).into_response())
        }
        Err(SubmitError::QueueFull(n)) => Err(ApiError {
            retry_after: Some(5),
            ..ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                "queue_full",
                format!("{n} jobs are waiting; try again later"),
            )
        }),
        Err(e @ SubmitError::OwnerQueueFull { .. }) => Err(ApiError {
            retry_after: Some(5),
            ..ApiError::new(StatusCode::TOO_MANY_REQUESTS, "queue_full", e.to_string())
        }),
        Err(SubmitError::Store(e)) => Err(ApiError::storage(e)),
    }
}

fn unknown_job(id: &str) -> ApiError {
    ApiError::new(StatusCode::NOT_FOUND, "unknown_job", format!("no job {id}"))
}

async fn find_job(service: &Service, id: &str) -> Result<Job, ApiError> {
    if !crate::store::job::is_id(id) {
        return Err(unknown_job(id));
    }
    service
        .job(id)
        .await
        .map_err(ApiError::storage)?
        .ok_or_else(|| unknown_job(id))
}

/// The recent jobs, newest first.
#[derive(Serialize, ToSchema)]
struct JobList {
    jobs: Vec<Job>,
}

#[utoipa::path(
    get, path = "/v1/jobs",
    params(("limit" = Option<usize>, Query, description = "How many, newest first: 1 to 500, default 50")),
    responses((status = 200, body = JobList), (status = 400, body = ErrorBody))
)]
async fn recent_jobs(
    State(state): State<AppState>,
    Query(params): Query<Vec<(String, String)>>,
) -> Result<Json<JobList>, ApiError> {
    let mut limit = 50;
    for (name, value) in &params {
        let bad = |message: String| ApiError::new(StatusCode::BAD_REQUEST, "bad_query", message);
        match (name.as_str(), value.parse::<usize>()) {
            ("limit", Ok(n @ 1..=500)) => limit = n,
            ("limit", _) => return Err(bad(format!("limit = {value}: expected 1 to 500"))),
            _ => return Err(bad(format!("unknown query parameter `{name}`"))),
        }
    }
    let jobs = state.service.recent_jobs(limit).await.map_err(ApiError::storage)?;
    Ok(Json(JobList { jobs }))
}

/// The queue and this node's workers: the figures of /metrics's gauges, for a read token.
#[utoipa::path(get, path = "/v1/activity", responses((status = 200, body = super::Activity)))]
async fn activity(State(state): State<AppState>) -> Result<Json<super::Activity>, ApiError> {
    Ok(Json(state.service.activity().await.map_err(ApiError::storage)?))
}

#[utoipa::path(
    get, path = "/v1/jobs/{id}",
    params(("id" = String, Path, description = "Job id")),
    responses((status = 200, body = Job), (status = 404, body = ErrorBody))
)]
async fn job_status(State(state): State<AppState>, Path(id): Path<String>) -> Result<Json<Job>, ApiError> {
    Ok(Json(find_job(&state.service, &id).await?))
}

#[utoipa::path(
    delete, path = "/v1/jobs/{id}",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Cancelled: the job as recorded, failed with code `cancelled`", body = Job),
        (status = 403, description = "With tokens: another token's job, and no `admin` scope", body = ErrorBody),
        (status = 404, body = ErrorBody),
        (status = 409, description = "The job has already ended", body = ErrorBody)
    )
)]
async fn cancel_job(
    State(state): State<AppState>,
    caller: Option<axum::Extension<Caller>>,
    Path(id): Path<String>,
) -> Result<Json<Job>, ApiError> {
    let job = find_job(&state.service, &id).await?;
    if let Some(axum::Extension(Caller(entry))) = &caller
        && !entry.scopes.contains(&Scope::Admin)
        && job.owner.as_deref() != Some(entry.name.as_str())
    {
        return Err(ApiError::new(
            StatusCode::FORBIDDEN,
            "forbidden",
            format!("job {id} was filed by another token: only its own or an `admin` token may cancel it"),
        ));
    }
    let ended = |job: Job| {
        ApiError::new(
            StatusCode::CONFLICT,
            "finished",
            format!("job {id} has already ended ({})", job.state.name()),
        )
    };
    if job.state.is_finished() {
        return Err(ended(job));
    }
    match state.service.cancel(job).await.map_err(ApiError::storage)? {
        Ok(cancelled) => Ok(Json(cancelled)),
        Err(Unwritten::Ended(job)) => Err(ended(*job)),
        Err(Unwritten::Gone) => Err(unknown_job(&id)),
    }
}

#[utoipa::path(
    get, path = "/v1/jobs/{id}/events",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Server-Sent Events: the job as JSON at each change, until it ends", content_type = "text/event-stream"),
        (status = 404, body = ErrorBody)
    )
)]
async fn job_events(
    State(state): State<AppState>,
    Path(id): Path<String>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let first = find_job(&state.service, &id).await?;
    let service = Arc::clone(&state.service);
    let shutdown = state.shutdown.clone();
    // (job to send now, last sent, ended)
    let events = stream::unfold((Some(first), None::<Job>, false), move |(next, sent, ended)| {
        let service = Arc::clone(&service);
        let shutdown = shutdown.clone();
        let id = id.clone();
        async move {
            if ended {
                return None;
            }
            let mut job = next;
            loop {
                if let Some(j) = job.take()
                    && Some(&j) != sent.as_ref()
                {
                    let event = Event::default()
                        .event(j.state.name())
                        .json_data(&j)
                        .expect("jobs serialize");
                    let ended = j.state.is_finished();
                    return Some((Ok(event), (None, Some(j), ended)));
                }
                if *shutdown.borrow() {
                    return None;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
                job = Some(service.job(&id).await.ok().flatten()?);
            }
        }
    });
    Ok(Sse::new(events).keep_alive(KeepAlive::default()))
}

/// A result was missing or broken: 404, saying whether it is being cooked again.
fn missing(key: &str, recook: Option<String>) -> ApiError {
    match recook {
        Some(job) => ApiError::new(
            StatusCode::NOT_FOUND,
            "recomputing",
            format!("the result for {key} failed its integrity check and is being cooked again by job {job}"),
        ),
        None => ApiError::new(
            StatusCode::NOT_FOUND,
            "unknown_key",
            format!("no occluder for key {key}"),
        ),
    }
}

fn check_key(key: &str) -> Result<(), ApiError> {
    if key.len() == 64 && key.bytes().all(|b| b.is_ascii_hexdigit()) {
        Ok(())
    } else {
        Err(ApiError::new(
            StatusCode::BAD_REQUEST,
            "bad_key",
            format!("`{key}` is not a key (64 hex digits)"),
        ))
    }
}

#[utoipa::path(
    get, path = "/v1/occluders/{key}",
    params(("key" = String, Path, description = "Content key (64 hex digits)")),
    responses(
        (status = 200, description = "The occluder GLB; ETag is the key, immutable", content_type = "model/gltf-binary"),
        (status = 304, description = "If-None-Match matched"),
        (status = 404, body = ErrorBody)
    )
)]
async fn occluder_glb(
    State(state): State<AppState>,
    Path(key): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    check_key(&key)?;
    let etag = format!("\"{key}\"");
    if let Some(not_modified) = not_modified(&state, &headers, &key, &etag).await? {
        return Ok(not_modified);
    }
    let cache_headers = immutable(&etag);
    match state.service.result_glb(&key).await.map_err(ApiError::storage)? {
        Ok(glb) => {
            let content_type = (header::CONTENT_TYPE, HeaderValue::from_static("model/gltf-binary"));
            Ok((StatusCode::OK, cache_headers, [content_type], glb).into_response())
        }
        Err(recook) => Err(missing(&key, recook)),
    }
}

#[utoipa::path(
    get, path = "/v1/occluders/{key}/report",
    params(("key" = String, Path, description = "Content key (64 hex digits)")),
    responses((status = 200, description = "The cook report", content_type = "application/json"), (status = 404, body = ErrorBody))
)]
async fn occluder_report(State(state): State<AppState>, Path(key): Path<String>) -> Result<Response, ApiError> {
    check_key(&key)?;
    match state.service.result_report(&key).await.map_err(ApiError::storage)? {
        Ok(report) => Ok(([(header::CONTENT_TYPE, "application/json")], report).into_response()),
        Err(recook) => Err(missing(&key, recook)),
    }
}

/// 304 Not Modified where If-None-Match names `etag` (or `*`) and the result of `key` is stored:
/// what a key names (its GLB, its preview) never changes while it is.
async fn not_modified(
    state: &AppState,
    headers: &HeaderMap,
    key: &str,
    etag: &str,
) -> Result<Option<Response>, ApiError> {
    let named = headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| {
            v.split(',')
                .map(str::trim)
                .any(|t| t == "*" || t.trim_start_matches("W/") == etag)
        });
    if !named
        || state
            .service
            .result_meta(key)
            .await
            .map_err(ApiError::storage)?
            .is_none()
    {
        return Ok(None);
    }
    Ok(Some((StatusCode::NOT_MODIFIED, immutable(etag)).into_response()))
}

/// The headers of what a key names, which never changes.
fn immutable(etag: &str) -> [(header::HeaderName, HeaderValue); 2] {
    [
        (header::ETAG, HeaderValue::from_str(etag).expect("hex is ASCII")),
        (
            header::CACHE_CONTROL,
            HeaderValue::from_static("public, max-age=31536000, immutable"),
        ),
    ]
}

#[utoipa::path(
    get, path = "/v1/occluders/{key}/preview.png",
    params(("key" = String, Path, description = "Content key (64 hex digits)")),
    responses(
        (status = 200, description = "A PNG sheet of four views: the original in grey, the occluder over it, false pixels in red; drawn once, immutable", content_type = "image/png"),
        (status = 304, description = "If-None-Match matched"),
        (status = 404, body = ErrorBody, description = "No result for the key, or its input is no longer kept")
    )
)]
async fn occluder_preview(
    State(state): State<AppState>,
    Path(key): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    check_key(&key)?;
    let etag = format!("\"{key}-preview\"");
    if let Some(not_modified) = not_modified(&state, &headers, &key, &etag).await? {
        return Ok(not_modified);
    }
    match state.service.preview(&key).await.map_err(ApiError::storage)? {
        Some(png) => {
            let content_type = (header::CONTENT_TYPE, HeaderValue::from_static("image/png"));
            Ok((StatusCode::OK, immutable(&etag), [content_type], png).into_response())
        }
        None => Err(ApiError::new(
            StatusCode::NOT_FOUND,
            "no_preview",
            format!("no result for key {key} to draw, or its inputs are no longer kept"),
        )),
    }
}

#[utoipa::path(
    get, path = "/v1/levels/{key}/preview.png",
    params(("key" = String, Path, description = "The level's content key (64 hex digits)")),
    responses(
        (status = 200, description = "A PNG sheet: a top view of the instances by batch, and three cull-test cameras with the culled instances seen through the walls; drawn once, immutable", content_type = "image/png"),
        (status = 304, description = "If-None-Match matched"),
        (status = 404, body = ErrorBody, description = "No result for the key, or its meshes' uploads are no longer kept")
    )
)]
async fn level_preview(state: State<AppState>, key: Path<String>, headers: HeaderMap) -> Result<Response, ApiError> {
    occluder_preview(state, key, headers).await
}

#[utoipa::path(get, path = "/healthz", responses((status = 200, description = "Serving"), (status = 503, body = ErrorBody, description = "The store does not answer")))]
async fn healthz(State(state): State<AppState>) -> Result<Json<serde_json::Value>, ApiError> {
    let depth = state.service.queue_depth().await.map_err(ApiError::storage)?;
    Ok(Json(serde_json::json!({ "status": "ok", "queue_depth": depth })))
}

#[utoipa::path(get, path = "/metrics", responses((status = 200, description = "Prometheus text format", content_type = "text/plain")))]
async fn metrics_text(State(state): State<AppState>) -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
        state.metrics.render(),
    )
}

async fn openapi_json() -> Json<utoipa::openapi::OpenApi> {
    Json(ApiDoc::openapi())
}
