// tsog-stream web player: the page's entry module (plain ES module, no build step).
// Reads a scene's manifest (from tsog serve's /v1 API or any static origin), plays its time
// range with the chunks that ChunkStream keeps loaded and evaluated at t on the GPU, and shows
// controls and an overlay. See docs/design/player.md.
import * as pc from 'playcanvas';
import { ChunkStream } from './stream.js';
import { OrbitCamera } from './orbit.js';

const $ = (id) => document.getElementById(id);

/** Euler angles (degrees) that turn a scene's up axis to the engine's +y. 3DGS captures in
 * COLMAP convention are y-down: open them with ?up=-y. */
const UP_ROTATIONS = { y: [0, 0, 0], '-y': [0, 0, 180], z: [-90, 0, 0], '-z': [90, 0, 0] };

/** The page's configuration (written by the server) and its query: t, paused, manifest. */
function readConfig() {
    const config = JSON.parse($('tsog-config').textContent);
    const params = new URLSearchParams(window.location.search);
    const manifest = new URL(config.manifest, window.location.href);
    const number = (name) => {
        const value = Number.parseFloat(params.get(name) ?? '');
        return Number.isFinite(value) ? value : null;
    };
    const view = { yaw: number('yaw'), pitch: number('pitch'), distance: number('distance'), up: params.get('up') ?? 'y' };
    if (!(view.up in UP_ROTATIONS)) throw new Error(`up must be one of ${Object.keys(UP_ROTATIONS).join(', ')}`);
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

/** Show an error in the middle of the page (and keep it for tests). */
function fail(message) {
    const box = $('error');
    box.textContent = message;
    box.hidden = false;
    window.tsogPlayer = { ...(window.tsogPlayer ?? {}), error: message };
}

/** The application, a camera orbiting the scene's bounding box (turned so `up` is up). */
function createApp(manifest, view) {
    const canvas = $('view');
    const app = new pc.Application(canvas, { graphicsDeviceOptions: { antialias: false } });
    app.setCanvasFillMode(pc.FILLMODE_FILL_WINDOW);
    app.setCanvasResolution(pc.RESOLUTION_AUTO);
    window.addEventListener('resize', () => app.resizeCanvas());
    const camera = new pc.Entity('camera');
    camera.addComponent('camera', { clearColor: new pc.Color(0.07, 0.07, 0.07), fov: 60 });
    app.root.addChild(camera);
    const scene = new pc.Entity('scene');
    scene.setLocalEulerAngles(...UP_ROTATIONS[view.up]);
    app.root.addChild(scene);
    const box = manifest.scene.bbox;
    const center = new pc.Vec3(...box.min.map((v, i) => (v + box.max[i]) / 2));
    scene.getWorldTransform().transformPoint(center, center);
    const size = Math.hypot(...box.max.map((v, i) => v - box.min[i])) || 1;
    const orbit = new OrbitCamera(camera, canvas, center, view.distance ?? 1.2 * size);
    if (view.yaw !== null) orbit.yaw = view.yaw;
    if (view.pitch !== null) orbit.pitch = view.pitch;
    return { app, camera, orbit, scene };
}

/** Playback state: time, speed, loop, and what the controls show. */
class Playback {
    constructor(manifest, config) {
        this.start = manifest.scene.start_s;
        this.end = manifest.scene.end_s;
        this.t = config.t === null ? this.start : Math.min(Math.max(config.t, this.start), this.end);
        this.playing = !config.paused;
        this.speed = 1;
        this.loop = true;
        this.buffering = false;
    }

    /** Advance by dt seconds of wall time unless paused or waiting for chunks. */
    advance(dt) {
        if (!this.playing || this.buffering) return;
        this.t += dt * this.speed;
        if (this.t > this.end) {
            if (this.loop) this.t = this.start;
            else {
                this.t = this.end;
                this.playing = false;
            }
        }
    }

    get state() {
        if (this.buffering) return 'buffering';
        return this.playing ? 'playing' : 'paused';
    }
}

/** Wire the controls to the playback state. */
function bindControls(playback) {
    const scrub = $('scrub');
    scrub.min = String(playback.start);
    scrub.max = String(playback.end);
    scrub.step = String(Math.max((playback.end - playback.start) / 1000, 1e-4));
    $('play').addEventListener('click', () => { playback.playing = !playback.playing; });
    scrub.addEventListener('input', () => { playback.t = Number.parseFloat(scrub.value); });
    $('speed').addEventListener('change', (e) => { playback.speed = Number.parseFloat(e.target.value); });
    $('loop').addEventListener('change', (e) => { playback.loop = e.target.checked; });
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

/** Refresh the overlay and the controls (a few times a second is enough). */
function showState(playback, stream, fps) {
    const stats = stream.stats();
    $('o-t').textContent = playback.t.toFixed(3);
    $('o-fps').textContent = fps.toFixed(0);
    $('o-chunks').textContent = String(stats.shown.length);
    $('o-loaded').textContent = String(stats.ready);
    $('o-bytes').textContent = stats.bytes.toLocaleString('en');
    $('o-state').textContent = stats.error ? `${playback.state} (${stats.error})` : playback.state;
    $('play').textContent = playback.playing ? 'pause' : 'play';
    if (document.activeElement !== $('scrub')) $('scrub').value = String(playback.t);
    drawBuffered(playback, stream.buffered());
}

async function main() {
    const config = readConfig();
    const fetchLog = [];
    window.tsogPlayer = { fetchLog };
    const manifestUrl = config.query ? `${config.manifest.href}?${config.query}` : config.manifest.href;
    fetchLog.push(manifestUrl);
    const response = await fetch(manifestUrl).catch(() => {
        throw new Error(`cannot fetch ${manifestUrl} (network error, or its origin does not allow CORS)`);
    });
    if (!response.ok) throw new Error(`manifest: HTTP ${response.status} from ${manifestUrl}`);
    const manifest = await response.json();
    if (manifest.format !== 'tsogs') throw new Error(`${manifestUrl} is not a TSOG stream manifest`);
    const { app, camera, orbit, scene } = createApp(manifest, config.view);
    const stream = new ChunkStream(pc, app, scene, manifest, chunkUrlFor(config), fetchLog);
    const playback = new Playback(manifest, config);
    bindControls(playback);
    let fps = 0;
    let sinceShown = 1;
    app.on('update', (dt) => {
        playback.advance(dt);
        stream.update(playback.t, playback.playing, playback.loop);
        playback.buffering = !stream.covered(playback.t);
        orbit.update();
        fps = dt > 0 ? 0.9 * fps + 0.1 / dt : fps;
        sinceShown += dt;
        if (sinceShown >= 0.2) {
            sinceShown = 0;
            showState(playback, stream, fps);
        }
    });
    Object.assign(window.tsogPlayer, { pc, app, camera, orbit, stream, playback, manifest });
    app.start();
}

main().catch((err) => fail(`player error: ${err.message ?? err}`));
