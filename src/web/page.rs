//! The page (wasm32 only): reads the terrain named in the address's fragment
//! (`#terrain.relief`, or `#https://host/path/terrain.relief`, then `&key=value` options) with
//! `fetch` and `Range` headers, refines it progressively each animation frame, draws it with
//! wgpu (WebGL2) in the page's `<canvas>`, and answers `window.relief.status()` with what a
//! test or a person wants to know. Bad input is a message over the canvas and `status().error`.

use std::cell::RefCell;
use std::rc::Rc;

use glam::DVec3;
use serde::Serialize;
use wasm_bindgen::prelude::*;
use wasm_bindgen::JsCast;
use wasm_bindgen_futures::{spawn_local, JsFuture};
use web_sys::{HtmlCanvasElement, HtmlElement, Request, RequestInit, Response};

use relief_core::refine::progressive::HostedRequest;

use crate::draw::{near_for, FrameUniform, Readback, Renderer};
use crate::scene::{Orbit, Scene, FIRST_RANGE_BYTES};

/// What `window.relief.status()` returns (as a plain object).
#[derive(Clone, Debug, Default, Serialize)]
struct Status {
    /// The terrain's address, resolved against the page.
    url: String,
    /// The graphics backend and adapter.
    backend: String,
    /// Set once a frame had every record it needed, was drawn, and nothing was in flight.
    complete: bool,
    /// Milliseconds from the page's start to the first complete frame.
    first_complete_ms: Option<f64>,
    /// Round trips the first complete frame waited for (1: the opening request alone).
    first_complete_round_trips: Option<u64>,
    /// A one-line message for bad input or a failure (then nothing more happens).
    error: Option<String>,
    frames: u64,
    triangles: u64,
    requests: u64,
    bytes: u64,
    round_trips: u64,
    tolerance_px: f64,
    z_exaggeration: f64,
    width: u32,
    height: u32,
    /// Median milliseconds of refinement and of a whole frame, over the frames drawn so far.
    refine_ms_median: f64,
    frame_ms_median: f64,
    /// Mean milliseconds of refinement per frame (the browser's clock is coarse, 0.1 ms: over
    /// many frames the mean resolves what one reading cannot).
    refine_ms_mean: f64,
    /// Frames per second over the last second of frames drawn.
    fps: f64,
    /// Every byte range fetched, in order: `[start, end)`.
    ranges: Vec<(u64, u64)>,
    /// With `#readback=1`: the first complete frame's pixels are in `window.relief.pixels()`.
    readback_done: bool,
}

/// The options of the address's fragment.
struct Params {
    terrain: String,
    tolerance_px: f64,
    z_exaggeration: f64,
    eye: Option<DVec3>,
    look: Option<DVec3>,
    /// Degrees the orbit turns per frame (a turntable, for frame-rate figures); 0: still.
    spin_deg: f64,
    /// The HUD and the help line (off for screenshots compared with a reference).
    hud: bool,
    /// Bytes of the opening request (whole pages).
    first_bytes: u64,
    /// Which graphics API: WebGPU where the browser has an adapter, else WebGL2 (`auto`, the
    /// default), or one of them (`webgpu`, `webgl2`).
    gpu: GpuChoice,
    /// An image to drape (its address, relative to the page) and how much the hillshade lights it.
    imagery: Option<String>,
    imagery_shade: f32,
    /// Once the first complete frame is drawn, draw it again into a texture and read it back
    /// (`window.relief.pixels()`): what tests compare where a canvas cannot be screenshot.
    readback: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum GpuChoice {
    Auto,
    WebGl2,
    WebGpu,
}

fn parse_params(fragment: &str) -> Result<Params, String> {
    let mut parts = fragment.trim_start_matches('#').split('&');
    let terrain = parts.next().unwrap_or_default().trim().to_string();
    let mut p = Params {
        terrain,
        tolerance_px: 2.0,
        z_exaggeration: 1.0,
        eye: None,
        look: None,
        spin_deg: 0.0,
        hud: true,
        first_bytes: FIRST_RANGE_BYTES,
        gpu: GpuChoice::Auto,
        readback: false,
        imagery: None,
        imagery_shade: 0.7,
    };
    let number =
        |key: &str, v: &str| v.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or(format!("#{key}={v}: not a number"));
    let point = |key: &str, v: &str| -> Result<DVec3, String> {
        let c: Vec<f64> = v.split(',').map(|c| number(key, c)).collect::<Result<_, _>>()?;
        match c[..] {
            [x, y, z] => Ok(DVec3::new(x, y, z)),
            _ => Err(format!("#{key}={v}: expected X,Y,Z metres")),
        }
    };
    for kv in parts.filter(|s| !s.is_empty()) {
        let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
        let v = &*js_sys::decode_uri_component(v).map(String::from).unwrap_or_else(|_| v.to_string());
        match k {
            "tau" => p.tolerance_px = number(k, v)?.clamp(0.1, 100.0),
            "z" => p.z_exaggeration = number(k, v)?,
            "eye" => p.eye = Some(point(k, v)?),
            "look" => p.look = Some(point(k, v)?),
            "spin" => p.spin_deg = number(k, v)?,
            "hud" => p.hud = v != "0",
            "first" => {
                let b = number(k, v)?;
                if !(4096.0..=1e9).contains(&b) {
                    return Err(format!("#first={v}: the opening request must be 4096 bytes to 1 GB"));
                }
                p.first_bytes = (b as u64).div_ceil(4096) * 4096;
            }
            "gpu" => {
                p.gpu = match v {
                    "auto" => GpuChoice::Auto,
                    "webgl2" => GpuChoice::WebGl2,
                    "webgpu" => GpuChoice::WebGpu,
                    _ => return Err(format!("#gpu={v}: expected auto, webgl2 or webgpu")),
                }
            }
            "readback" => p.readback = v != "0",
            "imagery" => p.imagery = Some(v.to_string()),
            "shade" => {
                let x = number(k, v)?;
                if !(0.0..=1.0).contains(&x) {
                    return Err(format!("#shade={v}: how much the hillshade lights the image, 0 to 1"));
                }
                p.imagery_shade = x as f32;
            }
            _ => {
                return Err(format!(
                    "#{k}: unknown option (tau, z, eye, look, spin, hud, first, gpu, readback, imagery, shade)"
                ))
            }
        }
    }
    if !(1.0..=100.0).contains(&p.z_exaggeration) {
        return Err(format!("#z={}: the vertical exaggeration must be between 1 and 100", p.z_exaggeration));
    }
    Ok(p)
}

fn window() -> web_sys::Window {
    web_sys::window().expect("a page has a window")
}

fn now_ms() -> f64 {
    window().performance().map_or(0.0, |p| p.now())
}

fn element<T: JsCast>(id: &str) -> Result<T, String> {
    window()
        .document()
        .and_then(|d| d.get_element_by_id(id))
        .and_then(|e| e.dyn_into::<T>().ok())
        .ok_or(format!("the page has no #{id} element of the right kind"))
}

fn js_message(e: &JsValue) -> String {
    e.dyn_ref::<js_sys::Error>()
        .map(|e| String::from(e.message()))
        .or_else(|| e.as_string())
        .unwrap_or_else(|| format!("{e:?}"))
}

/// Fetches bytes `[start, end)` of `url`; the answer must be that range (206 with a matching
/// `Content-Range`). Returns the body and the file's length.
async fn fetch_range(url: &str, start: u64, end: u64) -> Result<(Vec<u8>, u64), String> {
    let init = RequestInit::new();
    init.set_method("GET");
    let request = Request::new_with_str_and_init(url, &init).map_err(|e| format!("{url}: {}", js_message(&e)))?;
    request
        .headers()
        .set("Range", &format!("bytes={start}-{}", end - 1))
        .map_err(|e| format!("{url}: {}", js_message(&e)))?;
    let answer = JsFuture::from(window().fetch_with_request(&request)).await.map_err(|e| {
        format!(
            "{url}: could not be fetched ({}): the server is unreachable, or it refuses cross-origin reads \
             (CORS: it must send Access-Control-Allow-Origin)",
            js_message(&e)
        )
    })?;
    let response: Response =
        answer.dyn_into().map_err(|_| format!("{url}: fetch answered something not a Response"))?;
    match response.status() {
        206 => {}
        200 => {
            return Err(format!(
                "{url}: the server does not support range requests (it answered a Range request with the whole \
                 file); relief reads terrain files in ranges"
            ))
        }
        s => return Err(format!("{url}: the server answered {s} {}", response.status_text())),
    }
    let range = response.headers().get("Content-Range").ok().flatten().ok_or(format!(
        "{url}: the answer's Content-Range cannot be read (a server on another origin must list it in \
         Access-Control-Expose-Headers)"
    ))?;
    let (got_start, len) = parse_content_range(&range).ok_or(format!("{url}: a Content-Range of '{range}'"))?;
    let body = JsFuture::from(response.array_buffer().map_err(|e| format!("{url}: {}", js_message(&e)))?)
        .await
        .map_err(|e| format!("{url}: the body was cut off ({})", js_message(&e)))?;
    let bytes = js_sys::Uint8Array::new(&body).to_vec();
    let want = end.min(len).saturating_sub(start);
    if got_start != start || bytes.len() as u64 != want {
        return Err(format!("{url}: asked for bytes {start}..{end}, got {} at {got_start}", bytes.len()));
    }
    Ok((bytes, len))
}

/// `bytes a-b/len` → (a, len).
fn parse_content_range(v: &str) -> Option<(u64, u64)> {
    let rest = v.trim().strip_prefix("bytes ")?;
    let (span, len) = rest.split_once('/')?;
    let (a, _) = span.split_once('-')?;
    Some((a.trim().parse().ok()?, len.trim().parse().ok()?))
}

/// What to tell a person whose file did not open; a newer file says to update the viewer.
fn open_error(url: &str, e: relief_core::Error) -> String {
    use relief_core::error::Problem;
    match &e {
        relief_core::Error::File { problem: Problem::Version { found, supported, .. }, .. } if found > supported => {
            format!(
                "{url}: the file is version {found}, newer than this viewer (it reads terrain files up to version \
                 {supported}); serve it with a newer relief (relief serve --viewer)"
            )
        }
        relief_core::Error::File { problem: Problem::BadMagic, .. } => {
            format!("{url}: not a relief terrain file (convert a DEM with `relief convert`)")
        }
        _ => e.to_string(),
    }
}

/// Everything the page holds once the terrain is open.
struct App {
    /// Kept for the page's life with the adapter: the browser's WebGPU stops serving mappings
    /// ("no valid external Instance") once they go.
    _instance: wgpu::Instance,
    _adapter: wgpu::Adapter,
    scene: Scene,
    orbit: Orbit,
    url: String,
    device: wgpu::Device,
    queue: wgpu::Queue,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    renderer: Renderer,
    canvas: HtmlCanvasElement,
    hud: HtmlElement,
    status: Rc<RefCell<Status>>,
    started_ms: f64,
    /// Something changed since the last frame drawn (view, size, data): draw again.
    dirty: bool,
    spin_deg: f64,
    refine_ms: Vec<f64>,
    frame_ms: Vec<f64>,
    frame_times: std::collections::VecDeque<f64>,
    drag: Option<(i16, f64, f64)>,
    pinch: Option<f64>,
    failed: bool,
    readback: bool,
    /// Nothing is drawn to the canvas (a WebGPU read-back: see `draw_frame`).
    canvas_off: bool,
    pixels: Rc<RefCell<Option<String>>>,
    drape: Option<Drape>,
}

/// The draped image: its mip levels, where it lies, how it is lit.
struct Drape {
    levels: Vec<crate::draw::Level>,
    uv: [f32; 4],
    wraps: bool,
    shade: f32,
}

/// Fetches the image at `url` whole (decoded by the browser) and the world file beside it, if
/// any, and places it on `header`'s terrain.
async fn fetch_drape(url: &str, shade: f32, header: &relief_core::format::terrain::Header) -> Result<Drape, String> {
    let answer = JsFuture::from(window().fetch_with_str(url)).await.map_err(|e| {
        format!("{url}: could not be fetched ({}), or the server refuses cross-origin reads", js_message(&e))
    })?;
    let response: Response =
        answer.dyn_into().map_err(|_| format!("{url}: fetch answered something not a Response"))?;
    if !response.ok() {
        return Err(format!("{url}: the server answered {} {}", response.status(), response.status_text()));
    }
    let blob: web_sys::Blob = JsFuture::from(response.blob().map_err(|e| format!("{url}: {}", js_message(&e)))?)
        .await
        .map_err(|e| format!("{url}: the body was cut off ({})", js_message(&e)))?
        .unchecked_into();
    let options = web_sys::ImageBitmapOptions::new();
    options.set_color_space_conversion(web_sys::ColorSpaceConversion::None);
    options.set_premultiply_alpha(web_sys::PremultiplyAlpha::None);
    let not_image = |_| format!("{url}: not an image this browser decodes (PNG or JPEG)");
    let promise =
        window().create_image_bitmap_with_blob_and_image_bitmap_options(&blob, &options).map_err(not_image)?;
    let bitmap: web_sys::ImageBitmap = JsFuture::from(promise).await.map_err(not_image)?.unchecked_into();
    let (w, h) = (bitmap.width(), bitmap.height());
    let document = window().document().ok_or("no document")?;
    let canvas: HtmlCanvasElement = document.create_element("canvas").map_err(|e| js_message(&e))?.unchecked_into();
    canvas.set_width(w);
    canvas.set_height(h);
    let context: web_sys::CanvasRenderingContext2d = canvas
        .get_context("2d")
        .map_err(|e| js_message(&e))?
        .ok_or("no 2D canvas to decode the image in")?
        .unchecked_into();
    context.draw_image_with_image_bitmap(&bitmap, 0.0, 0.0).map_err(|e| js_message(&e))?;
    let rgba = context.get_image_data(0.0, 0.0, w as f64, h as f64).map_err(|e| js_message(&e))?.data().0;
    // The world file beside it, by the usual names; none: the image spans the DEM.
    let mut placement = None;
    if let Some((stem, ext)) = url.rsplit_once('.') {
        for wext in relief_core::georef::drape::world_file_extensions(&ext.to_ascii_lowercase()) {
            let wf = format!("{stem}.{wext}");
            let Ok(answer) = JsFuture::from(window().fetch_with_str(&wf)).await else { continue };
            let Ok(response) = answer.dyn_into::<Response>() else { continue };
            if !response.ok() {
                continue;
            }
            let text = match response.text() {
                Ok(p) => JsFuture::from(p).await.ok().and_then(|t| t.as_string()).unwrap_or_default(),
                Err(_) => String::new(),
            };
            placement =
                Some(relief_core::georef::drape::parse_world_file(&text).map_err(|what| format!("{wf}: {what}"))?);
            break;
        }
    }
    let (uv, wraps) = relief_core::georef::drape::uv_of_grid(w, h, placement, header.valid_window, header.georef).ok_or_else(|| {
        format!("{url}: its world file places it in a CRS, and the terrain has none (serve the image without it to stretch it over the DEM)")
    })?;
    Ok(Drape { levels: crate::draw::mip_levels(w, h, rgba), uv, wraps, shade })
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

impl App {
    fn fail(&mut self, message: String) {
        self.failed = true;
        show_error(&self.status, &message);
    }

    /// One animation frame: refine if anything changed, draw, ask for what was missed.
    fn frame(app: &Rc<RefCell<App>>) {
        let mut a = app.borrow_mut();
        if a.failed {
            return;
        }
        if let Err(e) = a.draw_frame() {
            a.fail(e);
            return;
        }
        loop {
            match a.scene.take_request() {
                Ok(Some(request)) => spawn_fetch(app.clone(), a.url.clone(), request),
                Ok(None) => break,
                Err(e) => {
                    a.fail(e.to_string());
                    return;
                }
            }
        }
    }

    fn draw_frame(&mut self) -> Result<(), String> {
        let t0 = now_ms();
        // WebGL2 maps buffers (a read-back) only when polled; WebGPU ignores it.
        let _ = self.device.poll(wgpu::PollType::Poll);
        let dpr = window().device_pixel_ratio().max(1.0);
        let (w, h) = (
            ((self.canvas.client_width() as f64 * dpr) as u32).max(1),
            ((self.canvas.client_height() as f64 * dpr) as u32).max(1),
        );
        if (w, h) != (self.config.width, self.config.height) {
            self.canvas.set_width(w);
            self.canvas.set_height(h);
            self.config.width = w;
            self.config.height = h;
            self.surface.configure(&self.device, &self.config);
            self.dirty = true;
        }
        if self.spin_deg != 0.0 {
            self.orbit.yaw_deg = (self.orbit.yaw_deg + self.spin_deg).rem_euclid(360.0);
            self.dirty = true;
        }
        if !self.dirty {
            return Ok(());
        }
        self.dirty = false;
        let camera = self.orbit.camera(w, h).map_err(|e| e.to_string())?;
        let r0 = now_ms();
        let progress = self.scene.refine(&camera).map_err(|e| e.to_string())?;
        self.refine_ms.push(now_ms() - r0);
        let look = self.scene.look();
        let positions = self.scene.positions(&look, self.drape.as_ref().map(|d| d.uv));
        self.renderer.set_strip(&self.device, &self.queue, &positions);
        let with_imagery = |u: FrameUniform| match &self.drape {
            Some(d) => u.with_imagery(d.shade, d.wraps),
            None => u,
        };
        // Read back on WebGPU, the canvas is left alone: headless Chromium's SwiftShader refuses
        // every mapAsync once a WebGPU canvas has shown a frame (ARCHITECTURE.md, "The web viewer").
        if !self.canvas_off {
            let frame = match self.surface.get_current_texture() {
                wgpu::CurrentSurfaceTexture::Success(f) | wgpu::CurrentSurfaceTexture::Suboptimal(f) => f,
                other => {
                    // Lost or outdated (a resize under way): configure again and draw next frame.
                    self.surface.configure(&self.device, &self.config);
                    self.dirty = true;
                    drop(other);
                    return Ok(());
                }
            };
            let view = frame
                .texture
                .create_view(&wgpu::TextureViewDescriptor { format: Some(self.config.format), ..Default::default() });
            let uniform = with_imagery(FrameUniform::new(
                &camera,
                &look,
                near_for(self.orbit.distance_m),
                self.renderer.srgb_target(),
            ));
            self.renderer.draw(&self.device, &self.queue, &view, (w, h), &uniform);
            self.queue.present(frame);
        }
        let end = now_ms();
        self.frame_ms.push(end - t0);
        self.frame_times.push_back(end);
        while self.frame_times.front().is_some_and(|&t| end - t > 1000.0) {
            self.frame_times.pop_front();
        }
        // Still coarse: the next frame refines again with what arrives meanwhile.
        if !progress.complete() {
            self.dirty = true;
        }
        let net = self.scene.network();
        let complete = progress.complete() && self.scene.outstanding() == 0;
        let mut s = self.status.borrow_mut();
        s.frames += 1;
        s.triangles = self.scene.triangles();
        s.requests = net.requests;
        s.bytes = net.bytes;
        s.round_trips = progress.round_trips;
        s.complete = complete;
        if complete && s.first_complete_ms.is_none() {
            s.first_complete_ms = Some(end - self.started_ms);
            s.first_complete_round_trips = Some(progress.round_trips);
            if self.readback {
                read_back(
                    Readback::draw(
                        &self.device,
                        &self.queue,
                        &positions,
                        self.drape.as_ref().map(|d| (&d.levels[..], d.wraps)),
                        (w, h),
                        &with_imagery(FrameUniform::new(&camera, &look, near_for(self.orbit.distance_m), true)),
                    ),
                    self.status.clone(),
                    self.pixels.clone(),
                );
            }
        }
        s.tolerance_px = self.scene.options.tolerance_px;
        s.z_exaggeration = self.scene.options.z_exaggeration;
        (s.width, s.height) = (w, h);
        s.refine_ms_median = median(&self.refine_ms);
        s.refine_ms_mean = self.refine_ms.iter().sum::<f64>() / self.refine_ms.len().max(1) as f64;
        s.frame_ms_median = median(&self.frame_ms);
        s.fps = self.frame_times.len() as f64;
        let hud = format!(
            "τ {:.1} px · {} triangles · {} in {} requests · refine {:.1} ms · frame {:.1} ms{}",
            s.tolerance_px,
            s.triangles,
            fmt_bytes(s.bytes),
            s.requests,
            self.refine_ms.last().copied().unwrap_or(0.0),
            s.frame_ms_median,
            if complete { "" } else { " · loading" }
        );
        drop(s);
        self.hud.set_inner_text(&hud);
        Ok(())
    }
}

fn fmt_bytes(b: u64) -> String {
    match b {
        0..1_000_000 => format!("{:.0} kB", b as f64 / 1e3),
        _ => format!("{:.1} MB", b as f64 / 1e6),
    }
}

/// Fetches every range of `request` (concurrently), inserts them, and delivers the request
/// once the last has arrived.
fn spawn_fetch(app: Rc<RefCell<App>>, url: String, request: HostedRequest) {
    let left = Rc::new(RefCell::new((request.ranges.len(), Some(request.clone()))));
    for &(start, end) in &request.ranges {
        let (app, url, left) = (app.clone(), url.clone(), left.clone());
        spawn_local(async move {
            let got = fetch_range(&url, start, end).await;
            let mut a = app.borrow_mut();
            if a.failed {
                return;
            }
            let result = got.and_then(|(bytes, _)| {
                a.status.borrow_mut().ranges.push((start, end));
                a.scene.insert(start, &bytes).map_err(|e| e.to_string())
            });
            if let Err(e) = result {
                a.fail(e);
                return;
            }
            let mut l = left.borrow_mut();
            l.0 -= 1;
            if l.0 == 0 {
                if let Some(r) = l.1.take() {
                    if let Err(e) = a.scene.deliver(r) {
                        a.fail(e.to_string());
                        return;
                    }
                    a.dirty = true;
                }
            }
        });
    }
}

/// Maps `readback` and, once mapped, keeps its pixels (RGBA8 rows from the top, base64) for
/// `window.relief.pixels()`.
fn read_back(readback: Readback, status: Rc<RefCell<Status>>, pixels: Rc<RefCell<Option<String>>>) {
    let mut resolve: Option<js_sys::Function> = None;
    let mapped = js_sys::Promise::new(&mut |res, _| resolve = Some(res));
    readback.map(move |r| {
        if let Some(f) = resolve {
            let answer = match r {
                Ok(()) => JsValue::NULL,
                Err(e) => JsValue::from_str(&e.to_string()),
            };
            let _ = f.call1(&JsValue::NULL, &answer);
        }
    });
    spawn_local(async move {
        let answer = JsFuture::from(mapped).await.unwrap_or(JsValue::NULL);
        if let Some(e) = answer.as_string() {
            show_error(&status, &format!("reading the frame back: the buffer could not be mapped ({e})"));
            return;
        }
        match readback.pixels() {
            Ok(rgba) => {
                use base64::Engine;
                *pixels.borrow_mut() = Some(base64::engine::general_purpose::STANDARD.encode(rgba));
                status.borrow_mut().readback_done = true;
            }
            Err(e) => show_error(&status, &e),
        }
    });
}

fn show_error(status: &Rc<RefCell<Status>>, message: &str) {
    status.borrow_mut().error = Some(message.to_string());
    if let Ok(e) = element::<HtmlElement>("message") {
        e.set_inner_text(message);
        let _ = e.style().set_property("display", "block");
    }
    web_sys::console::error_1(&JsValue::from_str(message));
}

thread_local! {
    /// The page's status, for the GPU's error handler.
    static GPU_STATUS: RefCell<Option<Rc<RefCell<Status>>>> = const { RefCell::new(None) };
}

/// `window.relief = { status(), pixels() }`.
fn expose_status(status: Rc<RefCell<Status>>, pixels: Rc<RefCell<Option<String>>>) -> Result<(), String> {
    let get = Closure::<dyn Fn() -> JsValue>::new(move || {
        let json = serde_json::to_string(&*status.borrow()).unwrap_or_else(|_| "null".into());
        js_sys::JSON::parse(&json).unwrap_or(JsValue::NULL)
    });
    let relief = js_sys::Object::new();
    js_sys::Reflect::set(&relief, &"status".into(), get.as_ref()).map_err(|e| js_message(&e))?;
    let read = Closure::<dyn Fn() -> JsValue>::new(move || match &*pixels.borrow() {
        Some(b) => JsValue::from_str(b),
        None => JsValue::NULL,
    });
    js_sys::Reflect::set(&relief, &"pixels".into(), read.as_ref()).map_err(|e| js_message(&e))?;
    read.forget();
    js_sys::Reflect::set(&relief, &"version".into(), &env!("CARGO_PKG_VERSION").into()).map_err(|e| js_message(&e))?;
    js_sys::Reflect::set(&window(), &"relief".into(), &relief).map_err(|e| js_message(&e))?;
    get.forget();
    Ok(())
}

#[wasm_bindgen(start)]
pub fn start() {
    let status = Rc::new(RefCell::new(Status::default()));
    let pixels = Rc::new(RefCell::new(None));
    if let Err(e) = expose_status(status.clone(), pixels.clone()) {
        web_sys::console::error_1(&JsValue::from_str(&e));
    }
    // A new fragment is a new terrain or view: start again.
    let reload = Closure::<dyn Fn()>::new(|| {
        let _ = window().location().reload();
    });
    window().set_onhashchange(Some(reload.as_ref().unchecked_ref()));
    reload.forget();
    spawn_local(async move {
        if let Err(e) = run(status.clone(), pixels).await {
            show_error(&status, &e);
        }
    });
}

async fn run(status: Rc<RefCell<Status>>, pixels: Rc<RefCell<Option<String>>>) -> Result<(), String> {
    let started_ms = now_ms();
    let location = window().location();
    let fragment = location.hash().unwrap_or_default();
    let params = parse_params(&fragment)?;
    if params.terrain.is_empty() {
        return Err(
            "No terrain named: add its address after '#' (a file served beside this page, #terrain.relief, or a \
             URL on a server that allows CORS, #https://host/terrain.relief)"
                .into(),
        );
    }
    let href = location.href().map_err(|e| js_message(&e))?;
    let url = web_sys::Url::new_with_base(&params.terrain, &href)
        .map_err(|_| format!("#{}: not an address", params.terrain))?
        .href();
    status.borrow_mut().url = url.clone();
    let (first, len) = fetch_range(&url, 0, params.first_bytes).await?;
    status.borrow_mut().ranges.push((0, first.len() as u64));
    let mut scene = Scene::open(&url, len, &first).map_err(|e| open_error(&url, e))?;
    scene.options.tolerance_px = params.tolerance_px;
    scene.options.z_exaggeration = params.z_exaggeration;
    let drape = match &params.imagery {
        Some(i) => {
            let image_url =
                web_sys::Url::new_with_base(i, &href).map_err(|_| format!("#imagery={i}: not an address"))?.href();
            Some(fetch_drape(&image_url, params.imagery_shade, scene.terrain().header()).await?)
        }
        None => None,
    };
    let mut orbit = Orbit::overview(scene.terrain(), params.z_exaggeration);
    if let (Some(eye), Some(look)) = (params.eye, params.look) {
        // An explicit view (local metres, heights unexaggerated).
        orbit = Orbit::looking(eye, look, params.z_exaggeration);
    }

    let canvas: HtmlCanvasElement = element("canvas")?;
    let hud: HtmlElement = element("hud")?;
    if !params.hud {
        for id in ["hud", "help"] {
            if let Ok(e) = element::<HtmlElement>(id) {
                let _ = e.style().set_property("display", "none");
            }
        }
    }
    let backends = match params.gpu {
        GpuChoice::Auto => wgpu::Backends::BROWSER_WEBGPU | wgpu::Backends::GL,
        GpuChoice::WebGl2 => wgpu::Backends::GL,
        GpuChoice::WebGpu => wgpu::Backends::BROWSER_WEBGPU,
    };
    // Auto: WebGPU only where the browser gives an adapter (some expose `navigator.gpu` and
    // none); asked for by name, as asked.
    let descriptor = wgpu::InstanceDescriptor { backends, ..wgpu::InstanceDescriptor::new_without_display_handle() };
    let instance = match params.gpu {
        GpuChoice::Auto => wgpu::util::new_instance_with_webgpu_detection(descriptor).await,
        _ => wgpu::Instance::new(descriptor),
    };
    let surface = instance
        .create_surface(wgpu::SurfaceTarget::Canvas(canvas.clone()))
        .map_err(|e| format!("this browser gives no WebGPU or WebGL2 canvas ({e})"))?;
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions { compatible_surface: Some(&surface), ..Default::default() })
        .await
        .map_err(|e| match params.gpu {
            GpuChoice::WebGpu => format!("no WebGPU adapter in this browser ({e}); #gpu=webgl2 draws with WebGL2"),
            _ => format!("no graphics adapter ({e})"),
        })?;
    let info = adapter.get_info();
    let (device, queue) = adapter
        .request_device(&wgpu::DeviceDescriptor {
            label: Some("relief web"),
            required_limits: wgpu::Limits::downlevel_webgl2_defaults().using_resolution(adapter.limits()),
            ..Default::default()
        })
        .await
        .map_err(|e| format!("cannot open the {:?} device: {e}", info.backend))?;
    let dpr = window().device_pixel_ratio().max(1.0);
    let (w, h) =
        (((canvas.client_width() as f64 * dpr) as u32).max(1), ((canvas.client_height() as f64 * dpr) as u32).max(1));
    canvas.set_width(w);
    canvas.set_height(h);
    let mut config = surface.get_default_config(&adapter, w, h).ok_or("the canvas offers no surface format")?;
    let caps = surface.get_capabilities(&adapter);
    if let Some(f) = caps.formats.iter().find(|f| f.is_srgb()) {
        config.format = *f;
    }
    surface.configure(&device, &config);
    let mut renderer = Renderer::new(&device, &queue, config.format);
    if let Some(d) = &drape {
        renderer.set_image(&device, &queue, &d.levels, d.wraps);
    }
    // A GPU error (wgpu's default is to panic) is the page's one-line error. The handler must
    // be Send, so it finds the status through the page's one thread's local.
    GPU_STATUS.with(|g| *g.borrow_mut() = Some(status.clone()));
    device.on_uncaptured_error(std::sync::Arc::new(|e: wgpu::Error| {
        let first = e.to_string().lines().map(str::trim).filter(|l| !l.is_empty()).collect::<Vec<_>>().join(": ");
        GPU_STATUS.with(|g| {
            if let Some(status) = &*g.borrow() {
                show_error(status, &format!("graphics error: {first}"));
            }
        });
    }));
    status.borrow_mut().backend = format!("{:?}: {}", info.backend, info.name);

    let app = Rc::new(RefCell::new(App {
        _instance: instance,
        _adapter: adapter,
        scene,
        orbit,
        url,
        device,
        queue,
        surface,
        config,
        renderer,
        canvas: canvas.clone(),
        hud,
        status: status.clone(),
        started_ms,
        dirty: true,
        spin_deg: params.spin_deg,
        refine_ms: Vec::new(),
        frame_ms: Vec::new(),
        frame_times: Default::default(),
        drag: None,
        pinch: None,
        failed: false,
        readback: params.readback,
        canvas_off: params.readback && info.backend == wgpu::Backend::BrowserWebGpu,
        drape,
        pixels: pixels.clone(),
    }));
    controls(&app, &canvas)?;
    animate(app);
    Ok(())
}

/// Draws every animation frame.
fn animate(app: Rc<RefCell<App>>) {
    /// The frame callback, which asks for itself again.
    type Tick = Rc<RefCell<Option<Closure<dyn FnMut()>>>>;
    let tick: Tick = Rc::new(RefCell::new(None));
    let again = tick.clone();
    *tick.borrow_mut() = Some(Closure::new(move || {
        App::frame(&app);
        if let Some(f) = again.borrow().as_ref() {
            let _ = window().request_animation_frame(f.as_ref().unchecked_ref());
        }
    }));
    let first = tick.borrow();
    if let Some(f) = first.as_ref() {
        let _ = window().request_animation_frame(f.as_ref().unchecked_ref());
    }
}

fn listen<E: JsCast + 'static>(
    target: &web_sys::EventTarget,
    kind: &str,
    app: &Rc<RefCell<App>>,
    f: impl Fn(&mut App, E) + 'static,
) -> Result<(), String> {
    let app = app.clone();
    let handler = Closure::<dyn FnMut(web_sys::Event)>::new(move |e: web_sys::Event| {
        if let (Ok(e), Ok(mut a)) = (e.dyn_into::<E>(), app.try_borrow_mut()) {
            f(&mut a, e);
        }
    });
    let options = web_sys::AddEventListenerOptions::new();
    options.set_passive(false);
    target
        .add_event_listener_with_callback_and_add_event_listener_options(
            kind,
            handler.as_ref().unchecked_ref(),
            &options,
        )
        .map_err(|e| js_message(&e))?;
    handler.forget();
    Ok(())
}

/// Mouse: drag to orbit, right-drag or shift-drag to pan, wheel to zoom. Touch: one finger
/// orbits, two pinch. Keys: W A S D fly along the ground, Q E down and up, arrows orbit, + and −
/// change τ, [ and ] the exaggeration, R resets.
fn controls(app: &Rc<RefCell<App>>, canvas: &HtmlCanvasElement) -> Result<(), String> {
    let target: &web_sys::EventTarget = canvas.as_ref();
    listen(target, "contextmenu", app, |_, e: web_sys::MouseEvent| e.prevent_default())?;
    listen(target, "mousedown", app, |a, e: web_sys::MouseEvent| {
        let button = if e.shift_key() { 2 } else { e.button() };
        a.drag = Some((button, e.client_x() as f64, e.client_y() as f64));
    })?;
    let win: web_sys::EventTarget = window().into();
    listen(&win, "mouseup", app, |a, _: web_sys::MouseEvent| a.drag = None)?;
    listen(&win, "mousemove", app, |a, e: web_sys::MouseEvent| {
        let Some((button, x, y)) = a.drag else { return };
        let (nx, ny) = (e.client_x() as f64, e.client_y() as f64);
        let h = a.config.height;
        if button == 0 {
            a.orbit.rotate(nx - x, ny - y);
        } else {
            a.orbit.pan(nx - x, ny - y, h);
        }
        a.drag = Some((button, nx, ny));
        a.dirty = true;
    })?;
    listen(target, "wheel", app, |a, e: web_sys::WheelEvent| {
        e.prevent_default();
        a.orbit.zoom(-e.delta_y() / 100.0);
        a.dirty = true;
    })?;
    listen(target, "touchstart", app, |a, e: web_sys::TouchEvent| {
        e.prevent_default();
        let t = e.touches();
        match (t.get(0), t.get(1)) {
            (Some(p), Some(q)) => {
                a.pinch = Some(((p.client_x() - q.client_x()) as f64).hypot((p.client_y() - q.client_y()) as f64));
                a.drag = None;
            }
            (Some(p), None) => a.drag = Some((0, p.client_x() as f64, p.client_y() as f64)),
            _ => {}
        }
    })?;
    listen(target, "touchmove", app, |a, e: web_sys::TouchEvent| {
        e.prevent_default();
        let t = e.touches();
        match (t.get(0), t.get(1), a.pinch, a.drag) {
            (Some(p), Some(q), Some(d0), _) => {
                let d = ((p.client_x() - q.client_x()) as f64).hypot((p.client_y() - q.client_y()) as f64);
                if d0 > 0.0 && d > 0.0 {
                    a.orbit.zoom((d / d0).ln() / 0.9f64.recip().ln());
                }
                a.pinch = Some(d);
            }
            (Some(p), None, _, Some((_, x, y))) => {
                let (nx, ny) = (p.client_x() as f64, p.client_y() as f64);
                a.orbit.rotate(nx - x, ny - y);
                a.drag = Some((0, nx, ny));
            }
            _ => return,
        }
        a.dirty = true;
    })?;
    listen(target, "touchend", app, |a, _: web_sys::TouchEvent| {
        a.drag = None;
        a.pinch = None;
    })?;
    listen(&win, "keydown", app, |a, e: web_sys::KeyboardEvent| {
        let o = &mut a.scene.options;
        match e.key().as_str() {
            "+" | "=" => o.tolerance_px = (o.tolerance_px / 1.25).max(0.1),
            "-" | "_" => o.tolerance_px = (o.tolerance_px * 1.25).min(100.0),
            "]" => o.z_exaggeration = (o.z_exaggeration * 1.25).min(100.0),
            "[" => o.z_exaggeration = (o.z_exaggeration / 1.25).max(1.0),
            "ArrowLeft" => a.orbit.rotate(-20.0, 0.0),
            "ArrowRight" => a.orbit.rotate(20.0, 0.0),
            "ArrowUp" => a.orbit.rotate(0.0, -10.0),
            "ArrowDown" => a.orbit.rotate(0.0, 10.0),
            "r" | "R" => a.orbit = Orbit::overview(a.scene.terrain(), a.scene.options.z_exaggeration),
            "w" | "W" => a.orbit.fly(1.0, 0.0, 0.0),
            "s" | "S" => a.orbit.fly(-1.0, 0.0, 0.0),
            "a" | "A" => a.orbit.fly(0.0, -1.0, 0.0),
            "d" | "D" => a.orbit.fly(0.0, 1.0, 0.0),
            "q" | "Q" => a.orbit.fly(0.0, 0.0, -1.0),
            "e" | "E" => a.orbit.fly(0.0, 0.0, 1.0),
            _ => return,
        }
        a.dirty = true;
    })?;
    Ok(())
}
