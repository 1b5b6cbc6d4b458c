"""`bulgekit studio`: place text and pictures on the outer wall in a browser, see the bumps,
export or print; and make lithophanes. A local web app over the toolkit's own API.

    server.py    aiohttp on 127.0.0.1: the page, uploads, jobs with progress, downloads,
                 the guard that refuses other hosts, origins and requests without the token
    design.py    the page's design <-> a placement file; preview (strokes, points, messages
                 per item) and export, made by the same calls as `bulgekit build --placement`
    static/      the page (index.html, studio.js, studio.css); vendor/ holds three.js, copied
                 from npm by host/web/build.py when the package is built, never fetched at run time
"""
