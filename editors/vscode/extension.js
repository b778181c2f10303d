// The mechdsl extension's client: starts `mechdsl lsp` (the language server of the Python
// package, mechdsl/lsp.py) over standard input and output for every `.mech` file on disk,
// and the command "mechdsl: open preview", which starts `mechdsl view FILE --no-browser`
// (mechdsl/view) and opens its page in VS Code's Simple Browser beside the editor.
// Plain CommonJS, no build step: VS Code loads this file as it is (package.json "main").
'use strict';

const childProcess = require('child_process');
const path = require('path');
const vscode = require('vscode');
const { LanguageClient } = require('vscode-languageclient/node');

const DEFAULT_COMMAND = ['mechdsl', 'lsp'];
const SETTING = 'server.command'; // mechdsl.server.command
const INSTALL_HINT = 'pip install "mechdsl[lsp]"';

/** @type {LanguageClient | undefined} */
let client;

/** The first workspace folder's path, or undefined (a single file opened). */
function workspaceFolder() {
  const folders = vscode.workspace.workspaceFolders;
  return folders && folders.length > 0 ? folders[0].uri.fsPath : undefined;
}

/**
 * The server's command line from the setting mechdsl.server.command: an array of strings,
 * the program then its arguments. `${workspaceFolder}` is replaced by the first workspace
 * folder, and a relative program path (`.venv/bin/mechdsl`) is taken from that folder.
 * A value that is not a non-empty array of strings falls back to ["mechdsl", "lsp"].
 */
function serverCommand() {
  const configured = vscode.workspace.getConfiguration('mechdsl').get(SETTING);
  const valid = Array.isArray(configured) && configured.length > 0 &&
    configured.every((part) => typeof part === 'string') && configured[0].trim() !== '';
  const folder = workspaceFolder();
  const parts = (valid ? configured : DEFAULT_COMMAND).map((part) =>
    folder === undefined ? part : part.split('${workspaceFolder}').join(folder));
  let [command, ...args] = parts;
  if (folder !== undefined && !path.isAbsolute(command) &&
      (command.includes('/') || command.includes(path.sep))) {
    command = path.join(folder, command);
  }
  return { command, args };
}

function startFailed(command, args, err) {
  const detail = err && err.message ? err.message : String(err);
  vscode.window.showErrorMessage(
    `mechdsl: the language server could not start (${[command, ...args].join(' ')}: ` +
    `${detail}). Install it with ${INSTALL_HINT}, and if mechdsl is in a virtual ` +
    'environment set "mechdsl.server.command" to its path, e.g. ' +
    '["/path/.venv/bin/mechdsl", "lsp"].');
}

/** Create and start the client; resolves once it runs, or after the error is shown. */
async function startClient() {
  const { command, args } = serverCommand();
  const serverOptions = {
    command,
    args,
    // no `transport`: TransportKind.stdio would append "--stdio" to a user's command line
    // (which `mechdsl lsp` accepts, a wrapper script might not); an Executable without one
    // talks over stdin/stdout all the same
    options: workspaceFolder() === undefined ? {} : { cwd: workspaceFolder() },
  };
  const clientOptions = {
    documentSelector: [{ scheme: 'file', language: 'mech' }],
  };
  let created;
  try {
    created = new LanguageClient('mechdsl', 'mechdsl language server', serverOptions,
      clientOptions);
    client = created;
    await created.start();
  } catch (err) {
    if (created === undefined || client === created) {
      client = undefined;
    }
    startFailed(command, args, err);
  }
  return created;
}

async function stopClient() {
  const running = client;
  client = undefined;
  if (running !== undefined) {
    try {
      await running.stop();
    } catch (err) {
      // a server that never started, or already exited: nothing left to stop
    }
  }
}

/** The running previews: file path -> { process, url }. */
const previews = new Map();
const URL_LINE = /(http:\/\/127\.0\.0\.1:\d+\/[\w-]+\/)/;

/**
 * `mechdsl view FILE --no-browser` with the program of mechdsl.server.command (its "lsp"
 * argument replaced by the view's): resolves with the page's address, which the view
 * prints on its standard error, or rejects with what it printed before exiting.
 */
function startView(file) {
  const { command, args } = serverCommand();
  const at = args.lastIndexOf('lsp');
  const viewArgs = [...(at >= 0 ? args.slice(0, at) : args), 'view', file, '--no-browser'];
  return new Promise((resolve, reject) => {
    let proc;
    try {
      proc = childProcess.spawn(command, viewArgs, {
        cwd: workspaceFolder(), stdio: ['ignore', 'ignore', 'pipe'],
      });
    } catch (err) {
      reject(err);
      return;
    }
    let text = '';
    proc.stderr.setEncoding('utf8');
    proc.stderr.on('data', (chunk) => {
      text += chunk;
      const found = URL_LINE.exec(text);
      if (found) {
        previews.set(file, { process: proc, url: found[1] });
        resolve(found[1]);
      }
    });
    proc.on('error', reject);
    proc.on('exit', (code) => {
      previews.delete(file);
      reject(new Error(`exit ${code}: ${text.trim().slice(-400)}`));
    });
  });
}

/** The command "mechdsl: open preview": the view of the active .mech file, beside it. */
async function openPreview() {
  const editor = vscode.window.activeTextEditor;
  const doc = editor && editor.document;
  if (!doc || doc.uri.scheme !== 'file' || doc.languageId !== 'mech') {
    vscode.window.showErrorMessage('mechdsl: open a .mech file saved on disk to preview it.');
    return undefined;
  }
  const file = doc.uri.fsPath;
  try {
    const running = previews.get(file);
    const url = running ? running.url : await startView(file);
    await vscode.commands.executeCommand('simpleBrowser.show', url);
    return url;
  } catch (err) {
    const detail = err && err.message ? err.message : String(err);
    vscode.window.showErrorMessage(
      `mechdsl: the preview could not start (${detail}). It needs ` +
      'pip install "mechdsl[view]" in the environment of "mechdsl.server.command".');
    return undefined;
  }
}

function stopPreviews() {
  for (const { process: proc } of previews.values()) {
    proc.kill('SIGINT'); // the view stops cleanly on Ctrl-C
  }
  previews.clear();
}

async function activate(context) {
  context.subscriptions.push(
    vscode.commands.registerCommand('mechdsl.openPreview', openPreview));
  context.subscriptions.push(vscode.workspace.onDidChangeConfiguration(async (event) => {
    if (event.affectsConfiguration(`mechdsl.${SETTING}`)) {
      await stopClient();
      await startClient();
    }
  }));
  await startClient();
}

function deactivate() {
  stopPreviews();
  return stopClient();
}

module.exports = { activate, deactivate, serverCommand, openPreview };
