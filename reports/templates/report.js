// Restart every animation of a row at once, so methods are compared frame by frame (no network use).
document.querySelectorAll("button.sync").forEach(function (button) {
  button.addEventListener("click", function () {
    var row = document.getElementById(button.dataset.target);
    row.querySelectorAll("img").forEach(function (img) { var src = img.src; img.src = ""; img.src = src; });
  });
});
