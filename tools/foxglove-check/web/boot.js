// Boots the Foxglove Studio 1.48 app from @foxglove/studio-base's browser bundle, as
// packages/studio-web does (Root.tsx), with two differences for the check:
// - the layout storage is in memory and holds one layout, docs/foxglove-layout.json (fetched
//   from /layout.json), under the id "m6p"; the page's URL selects it with `layoutId=m6p`
//   (as "Import from file" would, the layout goes through Studio's own migrateLayout);
// - app settings live in memory (no leftovers between runs).
// The data source comes from the URL too: `ds=remote-file&ds.url=...` or
// `ds=foxglove-websocket&ds.url=ws://...`.
(async function boot() {
  const S = window; // the UMD bundle put studio-base's exports on the global object
  const React = window.React;

  class MemoryAppConfiguration {
    constructor(defaults) { this.values = new Map(Object.entries(defaults)); this.listeners = new Map(); }
    get(key) { return this.values.get(key); }
    async set(key, value) {
      this.values.set(key, value);
      for (const cb of this.listeners.get(key) ?? []) { cb(value); }
    }
    addChangeListener(key, cb) {
      if (!this.listeners.has(key)) { this.listeners.set(key, new Set()); }
      this.listeners.get(key).add(cb);
    }
    removeChangeListener(key, cb) { this.listeners.get(key)?.delete(cb); }
  }

  class MemoryLayoutStorage {
    constructor(layouts) { this.byNs = new Map(); this.initial = layouts; }
    ns(namespace) {
      if (!this.byNs.has(namespace)) {
        this.byNs.set(namespace, new Map(this.initial.map((l) => [l.id, l])));
      }
      return this.byNs.get(namespace);
    }
    async list(namespace) { return [...this.ns(namespace).values()]; }
    async get(namespace, id) { return this.ns(namespace).get(id); }
    async put(namespace, layout) { this.ns(namespace).set(layout.id, layout); return layout; }
    async delete(namespace, id) { this.ns(namespace).delete(id); }
    async importLayouts() {}
    async migrateUnnamespacedLayouts() {}
  }

  const layoutResponse = await fetch("/layout.json");
  if (!layoutResponse.ok) { throw new Error(`layout: HTTP ${layoutResponse.status}`); }
  const layoutData = await layoutResponse.json();
  const now = new Date().toISOString();
  const layout = S.migrateLayout({
    id: "m6p",
    name: "m6p-twin (docs/foxglove-layout.json)",
    permission: "CREATOR_WRITE",
    baseline: { data: layoutData, savedAt: now },
    working: undefined,
    syncInfo: undefined,
  });

  // Studio shows a one-time "Open settings to configure topics and layers" tooltip over the
  // 3D panel's toolbar; mark it seen, as after a first visit, so screenshots show the panel.
  const PROFILE_KEY = "studio.profile-data";
  const profile = JSON.parse(localStorage.getItem(PROFILE_KEY) ?? "{}");
  profile.onboarding = { settingsTooltipShownForPanelTypes: ["3D", "map", "Plot", "StateTransitions", "Table", "RawMessages", "RosOut"] };
  localStorage.setItem(PROFILE_KEY, JSON.stringify(profile));

  S.installDevtoolsFormatters?.();
  S.overwriteFetch();
  await S.waitForFonts();
  await S.initI18n();

  const appConfiguration = new MemoryAppConfiguration({});
  const layoutStorage = new MemoryLayoutStorage([layout]);
  const dataSources = [new S.FoxgloveWebSocketDataSourceFactory(), new S.RemoteDataSourceFactory()];

  window.ReactDOM.render(
    React.createElement(S.App, {
      deepLinks: [window.location.href],
      dataSources,
      appConfiguration,
      layoutStorage,
      extensionLoaders: [],
      enableGlobalCss: true,
    }),
    document.getElementById("root"),
  );
  window.__m6pBooted = true;
})().catch((err) => {
  window.__m6pBootError = String(err && err.stack || err);
  console.error("boot failed", err);
});
