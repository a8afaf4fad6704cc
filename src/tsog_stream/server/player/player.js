// tsog-stream web player: the page's entry module (plain ES module, no build step).
// Reads a scene's manifest (from tsog serve's /v1 API or any static origin), plays its time
// range with the chunks that ChunkStream keeps loaded and evaluated at t on the GPU, and shows
// controls and an overlay. See docs/design/player.md.
import * as pc from 'playcanvas';
import { ChunkStream } from './stream.js';
import { MAX_MANIFEST_BYTES, checkManifest, readCapped } from './check.js';
import { fadeWhenIdle } from './idle.js';
import { CameraControls } from './controls.js';
import { CATCH_UP, LiveFollow, isLive, liveTarget } from './live.js';
import { UP_CHOICES, capturePose, pivotDistance, sceneUp, upRotation } from './views.js';

const $ = (id) => document.getElementById(id);

const DEFAULT_FRAME_S = 1 / 30; // a frame step when the scene has no frame rate
/** The longest frame counted in full (the engine clamps to 0.1 s by default): playback follows
 * the wall clock when a software GPU draws 10 frames a second, not a longer gap (a hidden tab). */
const MAX_FRAME_S = 0.5;
const SETTLE_MS = 250; // frames drawn after a change, before the splats' own state (loading, sorting) takes over

/** The page's configuration (written by the server) and its query: t, paused, the camera
 * (camera=N, pose=tx,ty,tz,yaw,pitch,distance[,fov], or the older yaw/pitch/distance), up. */
function readConfig() {
    const config = JSON.parse($('tsog-config').textContent);
    const params = new URLSearchParams(window.location.search);
    const manifest = new URL(config.manifest, window.location.href);
    const number = (name) => {
        const value = Number.parseFloat(params.get(name) ?? '');
        return Number.isFinite(value) ? value : null;
    };
    const pose = (params.get('pose') ?? '').split(',').map(Number.parseFloat);
    const view = {
        yaw: number('yaw'),
        pitch: number('pitch'),
        distance: number('distance'),
        up: params.get('up'),
        camera: number('camera'),
        pose: (pose.length === 6 || pose.length === 7) && pose.every(Number.isFinite) ? pose : null,
    };
    if (view.up !== null && !UP_CHOICES.includes(view.up)) throw new Error(`up must be one of ${UP_CHOICES.join(', ')}`);
    return { ...config, manifest, view, t: number('t'), paused: params.has('paused') };
}

/** Where a chunk's bytes are: the /v1 chunk URL (immutable by its hash), or its file beside
 * the manifest on a static origin. */
function chunkUrlFor(config) {
    if (config.chunks) {
        const signed = config.query ? `&${config.query}` : '';
        return (c) => `${config.chunks}${c.id}.sog?v=${c.sha256}${signed}`;
    }
    return (c) => new URL(c.file, config.manifest).href;
}

/** The manifest's JSON, read up to MAX_MANIFEST_BYTES. */
async function readManifest(response, url) {
    const bytes = await readCapped(response, MAX_MANIFEST_BYTES, `${url}: more than ${MAX_MANIFEST_BYTES} bytes, not a manifest`);
    try {
        return JSON.parse(new TextDecoder().decode(bytes));
    } catch {
        throw new Error(`${url} is not a TSOG stream manifest (not JSON)`);
    }
}

/** Show an error in the middle of the page (and keep it for tests). */
function fail(message) {
    const box = $('error');
    box.textContent = message;
    box.hidden = false;
    window.tsogPlayer = { ...(window.tsogPlayer ?? {}), error: message };
}

/** The application: a camera, and the scene turned so its up axis is the engine's +y. */
function createApp(manifest, view) {
    const canvas = $('view');
    const app = new pc.Application(canvas, { graphicsDeviceOptions: { antialias: false } });
    app.maxDeltaTime = MAX_FRAME_S;
    app.setCanvasFillMode(pc.FILLMODE_FILL_WINDOW);
    app.setCanvasResolution(pc.RESOLUTION_AUTO);
    window.addEventListener('resize', () => app.resizeCanvas());
    const camera = new pc.Entity('camera');
    camera.addComponent('camera', { clearColor: new pc.Color(0.07, 0.07, 0.07), fov: 60 });
    app.root.addChild(camera);
    const scene = new pc.Entity('scene');
    const legacy = view.yaw !== null || view.pitch !== null || view.distance !== null;
    const turn = upRotation(pc, sceneUp(manifest, view.up, legacy));
    scene.setLocalRotation(turn);
    app.root.addChild(scene);
    const core = manifest.scene.core;
    const box = manifest.scene.bbox;
    const scale = core ? core.radius : Math.hypot(...box.max.map((v, i) => v - box.min[i])) / 2 || 1;
    const controls = new CameraControls(pc, camera, canvas, scale);
    const presets = (manifest.cameras ?? []).map((c) => capturePose(pc, c, turn));
    const opening = manifest.view ? capturePose(pc, manifest.view, turn) : null;
    const views = { turn, core, box, presets, opening };
    startView(controls, camera, manifest, view, views);
    controls.saveHome();
    return { app, camera, controls, scene, views };
}

/** Put the camera where the page's query, else the manifest, says. */
function startView(controls, camera, manifest, view, views) {
    const { turn, box } = views;
    const centre = turn.transformVector(new pc.Vec3(...box.min.map((v, i) => (v + box.max[i]) / 2)), new pc.Vec3());
    const preset = view.camera !== null ? views.presets[view.camera] : null;
    if (view.pose) {
        const [x, y, z, yaw, pitch, distance, fov] = view.pose;
        controls.setOrbit(new pc.Vec3(x, y, z), distance, yaw, pitch);
        if (fov > 0 && fov < 180) camera.camera.fov = fov;
        else if (views.opening) camera.camera.fov = views.opening.fov;
    } else if (preset || (views.opening && view.yaw === null && view.pitch === null && view.distance === null)) {
        showPose(controls, camera, preset ?? views.opening, views);
    } else { // yaw/pitch/distance around the bounding box's centre, as links always meant
        const size = Math.hypot(...box.max.map((v, i) => v - box.min[i])) || 1;
        controls.setOrbit(centre, view.distance ?? 1.2 * size, view.yaw ?? 0, view.pitch ?? -15);
    }
}

/** Look exactly as a capture camera (or the opening view) does. */
function showPose(controls, camera, pose, views) {
    camera.camera.fov = pose.fov;
    controls.setPose(pose.position, pose.rotation, pivotDistance(pc, pose, views.core, views.turn));
}

/** True for a static scene, a stream of one moment: no timeline, or no time between its
 * start and end (the page then shows no time controls and never plays). */
function isStill(scene) {
    return scene.timeline_type == null || scene.end_s <= scene.start_s;
}

/** Playback state: time, speed, loop, and what the controls show. A live stream (spec 8.8)
 * is played `target` seconds behind its edge, up to CATCH_UP faster while further behind, and
 * waits at the edge with its last picture; once its event ends it plays as a recorded one. */
class Playback {
    constructor(manifest, config) {
        this.start = manifest.scene.start_s;
        this.end = manifest.scene.end_s;
        this.still = isStill(manifest.scene) && !isLive(manifest);
        this.frame = manifest.scene.fps ? 1 / manifest.scene.fps : DEFAULT_FRAME_S;
        this.live = isLive(manifest);
        this.target = liveTarget(manifest);
        this.t = config.t === null ? this.liveStart() : this.clamp(config.t);
        this.openedBehind = this.end - this.t; // how far behind the edge it opened (tests, overlay)
        this.playing = !config.paused && !this.still;
        this.speed = 1;
        this.loop = !this.live;
        this.buffering = false;
    }

    clamp(t) {
        return Math.min(Math.max(t, this.start), this.end);
    }

    /** Where playback opens: the start, or a live stream's target behind its edge. */
    liveStart() {
        return this.live ? Math.max(this.start, this.end - this.target) : this.start;
    }

    /** A newer index of a live stream: its edge, and whether its event goes on. */
    follow(manifest) {
        this.end = manifest.scene.end_s;
        this.live = isLive(manifest);
    }

    /** Jump to the live edge's target and play. */
    goLive() {
        this.t = this.liveStart();
        this.playing = true;
    }

    /** Seconds behind the live edge beyond the target (0 when not live). */
    get behind() {
        return this.live ? this.end - this.t - this.target : 0;
    }

    /** Play or pause (a still scene stays as it is). */
    toggle() {
        this.playing = !this.playing && !this.still;
    }

    /** Advance by dt seconds of wall time unless paused or waiting for chunks; a live stream
     * catches up (at most CATCH_UP) and never passes its edge. */
    advance(dt) {
        if (!this.playing || this.buffering) return;
        const rate = this.behind > this.frame ? CATCH_UP : 1;
        this.t += dt * this.speed * rate;
        if (this.t > this.end) {
            if (this.live) this.t = this.end;
            else if (this.loop) this.t = this.start;
            else {
                this.t = this.end;
                this.playing = false;
            }
        }
    }

    /** Pause and move by `frames` frames (1/fps, or 1/30 s for a scene without a rate). */
    step(frames) {
        this.playing = false;
        this.t = this.clamp(this.t + frames * this.frame);
    }

    /** Move by `seconds`, playing or not. */
    skip(seconds) {
        this.t = this.clamp(this.t + seconds);
    }

    get state() {
        if (this.still) return 'still';
        if (this.buffering) return 'buffering';
        if (this.live && this.playing && this.t >= this.end) return 'waiting for the live edge';
        return this.playing ? 'playing' : 'paused';
    }
}

/** Seconds as the time display shows them: 12.34 s, 1:02.50 past a minute. */
function clock(seconds) {
    if (Math.abs(seconds) < 60) return `${seconds.toFixed(2)} s`;
    const m = Math.floor(seconds / 60);
    return `${m}:${(seconds - 60 * m).toFixed(2).padStart(5, '0')}`;
}

/** The duration label: marked, with the reason in its tooltip, when the length was assumed. */
function showDuration(end, assumed) {
    const label = $('duration');
    label.textContent = assumed ? `${clock(end)} (assumed)` : clock(end);
    label.classList.toggle('assumed', assumed);
    if (assumed) {
        label.title = 'assumed: the source format does not carry its length; '
            + 'tsog segment --duration-s SECONDS sets it';
    } else label.removeAttribute('title');
}

/** Fill the capture-camera preset list (hidden when the scene has none). */
function fillPresets(views) {
    const select = $('camera');
    select.replaceChildren(new Option(views.opening ? 'opening view' : 'start view', ''));
    views.presets.forEach((p, i) => select.add(new Option(`camera ${i}${p.name ? ` (${p.name})` : ''}`, String(i))));
    select.hidden = views.presets.length === 0;
}

/** The page's URL for the current time and camera: a preset still in view is named, any
 * other view is written as its pivot, angles and distance. */
function linkFor(playback, controls, preset, camera) {
    const url = new URL(window.location.href);
    for (const key of ['t', 'paused', 'camera', 'pose', 'yaw', 'pitch', 'distance']) url.searchParams.delete(key);
    url.searchParams.set('t', playback.t.toFixed(3));
    if (!playback.playing) url.searchParams.set('paused', '');
    if (preset.index !== null && preset.moved === controls.moved) url.searchParams.set('camera', String(preset.index));
    else if (controls.exact === null || preset.index === null) {
        const t = controls.target;
        const values = [t.x, t.y, t.z, controls.yaw, controls.pitch, controls.distance, camera.camera.fov];
        const pose = values.map((v) => Number(v.toFixed(4)));
        if (controls.moved > 0) url.searchParams.set('pose', pose.join(','));
    }
    return url.href.replace('paused=&', 'paused&').replace(/paused=$/, 'paused');
}

/** Wire the buttons, the scrub bar and the keyboard to playback and camera. */
function bindControls(playback, controls, views, camera, manifest) {
    showRange(playback, manifest);
    document.body.classList.toggle('still', playback.still);
    $('loop').checked = playback.loop; // a live stream does not loop
    const preset = { index: null, moved: 0 };
    const choose = (value) => {
        const index = value === '' ? null : Number(value);
        const pose = index === null ? null : views.presets[index];
        if (pose) {
            camera.camera.fov = pose.fov;
            controls.setPose(pose.position, pose.rotation, pivotDistance(pc, pose, views.core, views.turn));
            controls.moved += 1;
        } else controls.reset();
        preset.index = index;
        preset.moved = controls.moved;
        $('camera').value = value;
    };
    fillPresets(views);
    $('play').addEventListener('click', () => playback.toggle());
    $('live').addEventListener('click', () => playback.goLive());
    $('back').addEventListener('click', () => playback.step(-1));
    $('forward').addEventListener('click', () => playback.step(1));
    scrub.addEventListener('input', () => { playback.t = Number.parseFloat(scrub.value); });
    $('speed').addEventListener('change', (e) => { playback.speed = Number.parseFloat(e.target.value); });
    $('loop').addEventListener('change', (e) => { playback.loop = e.target.checked; });
    $('camera').addEventListener('change', (e) => choose(e.target.value));
    $('reset').addEventListener('click', () => choose(''));
    $('mode').addEventListener('click', () => {
        controls.mode = controls.mode === 'orbit' ? 'fly' : 'orbit';
        $('mode').textContent = controls.mode;
    });
    $('fullscreen').addEventListener('click', toggleFullscreen);
    $('link').addEventListener('click', () => copyLink(linkFor(playback, controls, preset, camera)));
    $('help').addEventListener('click', () => { $('keys').hidden = !$('keys').hidden; });
    bindKeys(playback, controls, choose);
    return { preset };
}

/** The scrub bar's range and the duration label (a live stream's grow with its edge). */
function showRange(playback, manifest) {
    const scrub = $('scrub');
    scrub.min = String(playback.start);
    scrub.max = String(playback.end);
    scrub.step = String(Math.max((playback.end - playback.start) / 1000, 1e-4));
    showDuration(playback.end, manifest.scene.duration_assumed === true);
}

/** The live badge: shown while the event goes on, lit at the edge, "go live" behind it. */
function showLive(playback) {
    const badge = $('live');
    badge.hidden = !playback.live;
    const behind = playback.behind > 1 || !playback.playing;
    badge.classList.toggle('behind', behind);
    badge.textContent = behind ? 'go live' : 'LIVE';
}

function toggleFullscreen() {
    if (document.fullscreenElement) document.exitFullscreen();
    else document.documentElement.requestFullscreen?.();
}

/** Put the link on the clipboard (where the page may) and show it either way. */
function copyLink(href) {
    window.tsogPlayer.link = href;
    const shown = $('copied');
    shown.textContent = href;
    shown.hidden = false;
    clearTimeout(copyLink.timer);
    copyLink.timer = setTimeout(() => { shown.hidden = true; }, 6000);
    navigator.clipboard?.writeText(href).then(
        () => { shown.textContent = `copied: ${href}`; },
        () => {},
    );
}

/** Keys: space play/pause, arrows frame step (shift: 1 s), WASD/QE fly, R reset, V fly mode,
 * F fullscreen, L loop, 0-9 capture cameras, ? help. Ignored while typing in a field. */
function bindKeys(playback, controls, choose) {
    window.addEventListener('keydown', (e) => {
        const field = e.target instanceof HTMLElement && e.target.matches('input[type=url], input[type=text], select');
        if (field || e.ctrlKey || e.metaKey || e.altKey) return;
        const actions = {
            Space: () => playback.toggle(),
            ArrowLeft: () => (e.shiftKey ? playback.skip(-1) : playback.step(-1)),
            ArrowRight: () => (e.shiftKey ? playback.skip(1) : playback.step(1)),
            Comma: () => playback.step(-1),
            Period: () => playback.step(1),
            Home: () => { playback.t = playback.start; },
            End: () => { playback.t = playback.end; },
            KeyR: () => choose(''),
            KeyV: () => $('mode').click(),
            KeyF: toggleFullscreen,
            KeyL: () => $('loop').click(),
            Slash: () => $('help').click(),
        };
        const digit = /^Digit([0-9])$/.exec(e.code);
        if (digit && $('camera').options.length > Number(digit[1]) + 1) {
            choose(digit[1]);
        } else if (actions[e.code]) {
            actions[e.code]();
        } else if (/^Key[WASDQE]$|^Shift/.test(e.code)) {
            controls.keys.add(e.code);
            return;
        } else return;
        e.preventDefault();
    });
    window.addEventListener('keyup', (e) => controls.keys.delete(e.code));
    window.addEventListener('blur', () => controls.keys.clear());
}

/** Draw the buffered time ranges above the scrub bar. */
function drawBuffered(playback, ranges) {
    const canvas = $('buffered');
    const width = canvas.clientWidth || 1;
    if (canvas.width !== width) canvas.width = width;
    const ctx = canvas.getContext('2d');
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    ctx.fillStyle = '#4a8';
    const span = playback.end - playback.start || 1;
    for (const [a, b] of ranges) {
        const x0 = ((Math.max(a, playback.start) - playback.start) / span) * width;
        const x1 = ((Math.min(b, playback.end) - playback.start) / span) * width;
        ctx.fillRect(x0, 0, Math.max(x1 - x0, 1), canvas.height);
    }
}

/** "2/3 layers (33.3 dB)": the layers drawn at t and what the manifest says they show. */
function quality(manifest, stats) {
    if (stats.layerCount <= 1) return 'full';
    if (stats.layers === 0) return `loading the base of ${stats.layerCount} layers`;
    const db = manifest.layers[stats.layers - 1]?.psnr_db;
    return `${stats.layers}/${stats.layerCount} layers (${db == null ? 'full' : `${db.toFixed(1)} dB`})`;
}

/** Refresh the overlay and the controls (a few times a second is enough). */
function showState(playback, stream, fps) {
    const stats = stream.stats();
    $('o-t').textContent = playback.t.toFixed(3);
    $('o-fps').textContent = fps.toFixed(0);
    $('o-chunks').textContent = String(stats.shown.length);
    $('o-loaded').textContent = String(stats.ready);
    $('o-bytes').textContent = stats.bytes.toLocaleString('en');
    $('o-quality').textContent = quality(stream.index.manifest, stats);
    $('o-state').textContent = stats.error ? `${playback.state} (${stats.error})` : playback.state;
    $('play').textContent = playback.playing ? 'pause' : 'play';
    $('time').textContent = clock(playback.t);
    showLive(playback);
    if (document.activeElement !== $('scrub')) $('scrub').value = String(playback.t);
    drawBuffered(playback, stream.buffered());
}

/** True while the splat sort of a view is under way or its result not yet drawn. */
function sortUnderWay(app) {
    let busy = false;
    app.renderer.gsplatDirector?.camerasMap.forEach((cameraData) => cameraData.layersMap.forEach((layerData) => {
        const sorter = layerData.gsplatManager?.cpuSorter;
        if (sorter && (sorter.jobsInFlight > 0 || sorter.pendingSorted)) busy = true;
    }));
    return busy;
}

/** Draw only when what is seen may have changed (time, camera, the chunks drawn, the canvas)
 * and until the splats are loaded and sorted for it: a still picture costs nothing to keep,
 * so the chunks still decoding get the CPU (where a software GPU draws too). Returns the
 * per-frame check; `redraw()` asks for a picture after a change made from outside. */
function drawOnChange(app, camera, stream) {
    app.autoRender = false;
    let seen = '';
    let settleUntil = 0;
    const redraw = () => { settleUntil = performance.now() + SETTLE_MS; };
    app.systems.gsplat.on('frame:ready', (_camera, _layer, ready, loading) => {
        if (!ready || loading > 0) app.renderNextFrame = true;
    });
    const check = (t) => {
        const { width, height } = app.graphicsDevice;
        const key = `${t}|${camera.getWorldTransform().data.join()}|${camera.camera.fov}|${stream.changes}|${width}x${height}`;
        if (key !== seen) {
            seen = key;
            redraw();
        }
        if (performance.now() < settleUntil || sortUnderWay(app)) app.renderNextFrame = true;
    };
    return { check, redraw };
}

/** A scene's index from `url`, checked (its fetch errors said in a way a viewer can act on). */
async function readIndex(url) {
    const response = await fetch(url, { cache: 'no-cache' }).catch(() => {
        throw new Error(`cannot fetch ${url} (network error, or its origin does not allow CORS)`);
    });
    if (response.status === 404) throw new Error(`scene not found: ${url} (HTTP 404)`);
    if (!response.ok) throw new Error(`manifest: HTTP ${response.status} from ${url}`);
    return checkManifest(await readManifest(response, url));
}

async function main() {
    const config = readConfig();
    const fetchLog = [];
    window.tsogPlayer = { fetchLog };
    const manifestUrl = config.query ? `${config.manifest.href}?${config.query}` : config.manifest.href;
    const read = (url) => {
        fetchLog.push(url);
        return readIndex(url);
    };
    const manifest = await read(manifestUrl);
    const { app, camera, controls, scene, views } = createApp(manifest, config.view);
    const stream = new ChunkStream(pc, app, scene, manifest, chunkUrlFor(config), fetchLog);
    const playback = new Playback(manifest, config);
    const { preset } = bindControls(playback, controls, views, camera, manifest);
    const fade = fadeWhenIdle(document.body, $('controls'));
    if (config.view.camera !== null && views.presets[config.view.camera]) {
        preset.index = config.view.camera;
        $('camera').value = String(config.view.camera);
    }
    const drawing = drawOnChange(app, camera, stream);
    let fps = 0;
    let sinceShown = 1;
    let layersOnShow = 0;
    app.on('update', (dt) => {
        playback.advance(dt);
        stream.update(playback.t, playback.playing, playback.loop);
        playback.buffering = !stream.playable(playback.t, playback.playing);
        fade(playback.playing);
        controls.update(dt);
        drawing.check(playback.t);
        fps = dt > 0 ? 0.9 * fps + 0.1 / dt : fps;
        sinceShown += dt;
        if (sinceShown >= 0.2 || stream.shownLayers !== layersOnShow) {
            // a few times a second, and at once when the quality drawn changes
            sinceShown = 0;
            layersOnShow = stream.shownLayers;
            showState(playback, stream, fps);
        }
    });
    Object.assign(window.tsogPlayer, { pc, app, camera, controls, stream, playback, manifest, views, redraw: drawing.redraw });
    if (isLive(manifest)) {
        const follow = new LiveFollow(manifestUrl, manifest, read, (fresh) => {
            stream.setManifest(fresh);
            playback.follow(fresh);
            showRange(playback, fresh);
            window.tsogPlayer.manifest = fresh;
            drawing.redraw();
        });
        window.tsogPlayer.live = follow;
        follow.run();
    }
    app.start();
}

main().catch((err) => fail(`player error: ${err.message ?? err}`));
